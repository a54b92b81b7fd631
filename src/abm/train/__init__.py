"""Training of the policy family: :class:`TrainConfig`, :class:`Trainer` and :func:`train` (single
process or ``torchrun`` DDP)."""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.train.config import TrainConfig
    from abm.train.loop import Trainer, parameter_digest, train

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = ["TrainConfig", "Trainer", "parameter_digest", "train"]
