"""Training of the policy family: :func:`train` (single process or ``torchrun`` DDP)."""

from abm.train.loop import TrainConfig, parameter_digest, train

__all__ = ["TrainConfig", "parameter_digest", "train"]
