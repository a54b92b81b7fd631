"""The options shared by every rollout of an evaluation (:class:`EvalSettings`; the ``abm eval`` flags besides
the run selection). Light, so the command line's parsers can use it; the rollouts are :mod:`abm.evaluation.runner`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from abm.configuration import CAMERA_RESOLUTION, MAX_KEYFRAMES
from abm.grounding.config import GROUNDERS, grounder_from_flags


@dataclass(frozen=True)
class EvalSettings:
    """Options shared by every rollout of an evaluation (the ``abm eval`` flags besides the run selection).

    Attributes:
        device: torch device of the policy (cpu, cuda).
        grounder: override the grounder stored in the checkpoint (clip, oracle; tracking = ground once per
            episode with the stored grounder, then track the target's points).
        resolution: camera resolution in pixels.
        max_steps: keyframes before an episode counts as failed.
        splits_path: object split file replacing the built-in one.
        clip_model: CLIP weights (hub name or folder) of the ``clip`` grounder or of ``tracking``'s first
            step; needs ``grounder`` clip or tracking ('tiny' and 'random:ARCH' are random weights, for tests only).
    """

    device: str = "cpu"
    grounder: str | None = field(default=None, metadata={"choices": GROUNDERS.names})
    resolution: int = CAMERA_RESOLUTION
    max_steps: int = MAX_KEYFRAMES
    splits_path: str | None = field(default=None, metadata={"flag": "--splits"})
    clip_model: str | None = None

    def __post_init__(self) -> None:
        if self.grounder is None and self.clip_model is None:
            return  # nothing to check
        grounder_from_flags(self.grounder, self.clip_model)  # a clear error for --clip-model without a CLIP grounder

    def signature(self) -> str:
        """Compact JSON of the settings that change outcomes (recorded with every outcome; ``clip_model``
        only when set, so outcomes recorded before it existed still match)."""
        fields = {k: v for k, v in asdict(self).items() if k != "device" and not (k == "clip_model" and v is None)}
        return json.dumps(fields, sort_keys=True)
