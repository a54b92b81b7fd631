"""Training of the policy family: :func:`train` (single process or ``torchrun`` DDP) and checkpoints."""

from abm.train.checkpoint import list_checkpoints, load_checkpoint, resolve_checkpoint, save_checkpoint
from abm.train.loop import TrainConfig, parameter_digest, train

__all__ = [
    "TrainConfig", "list_checkpoints", "load_checkpoint", "parameter_digest", "resolve_checkpoint",
    "save_checkpoint", "train",
]
