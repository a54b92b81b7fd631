"""abm: Attention before Manipulation — mask-conditioned multi-view manipulation policies and a MuJoCo benchmark."""

__version__ = "0.1.0"
