"""Training of the policy family: :class:`TrainConfig`, :class:`Trainer` and :func:`train` (single
process or ``torchrun`` DDP)."""

from abm.train.config import TrainConfig
from abm.train.loop import Trainer, parameter_digest, train

__all__ = ["TrainConfig", "Trainer", "parameter_digest", "train"]
