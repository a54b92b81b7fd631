"""Training of the policy family: :class:`TrainConfig`, :class:`Trainer` and :func:`train` (single
process or ``torchrun`` DDP)."""

from abm.lazy import lazy_exports

# imported on first use (abm.lazy), so importing the package (every `abm` command does) stays light
__getattr__, __dir__ = lazy_exports(__name__, {
    "abm.train.config": ("TrainConfig",),
    "abm.train.loop": ("Trainer", "parameter_digest", "train",),
})

__all__ = ["TrainConfig", "Trainer", "parameter_digest", "train"]
