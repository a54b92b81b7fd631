"""The options shared by every rollout of an evaluation (:class:`EvalSettings`; the ``abm eval`` flags besides
the run selection). Light, so the command line's parsers can use it; the rollouts are :mod:`abm.evaluation.runner`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from abm.configuration import CAMERA_RESOLUTION, MAX_KEYFRAMES
from abm.errors import ConfigError
from abm.grounding.config import GROUNDERS, grounder_from_flags

#: the tasks ``abm zoo eval`` runs by default: the paper's 8 (Table 1), all of them, so the choice does not depend
#: on which tasks the zoo's models happen to do well on
ZOO_EVAL_TASKS = ("close_jar", "insert_peg", "pick_block", "place_food", "place_wine", "put_in_shelf", "take_off_pan",
                  "water_plants")
ZOO_EVAL_EPISODES = 5  #: ``abm zoo eval``'s episodes per task and split (its time: abm.measured)
ZOO_EVAL_MAX_STEPS = 8  #: ``abm zoo eval``'s keyframes per episode
ZOO_EVAL_SPLITS = ("seen", "unseen")  #: ``abm zoo eval``'s object splits (its outcomes in ``OUT/SPLIT``)

EXPERT_KEYFRAME_KINDS = ("move",)
"""Keyframe kinds ``abm eval --expert-keyframes`` executes as the scripted expert's
(:mod:`abm.evaluation.expert_move`)."""


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
        expert_keyframes: execute the scripted expert's keyframe of this kind (move) instead of the policy's, by
            the rule of docs/evaluation.md (the reference of a perfect destination; outcomes keyed apart).
    """

    device: str = "cpu"
    grounder: str | None = field(default=None, metadata={"choices": GROUNDERS.names})
    resolution: int = CAMERA_RESOLUTION
    max_steps: int = MAX_KEYFRAMES
    splits_path: str | None = field(default=None, metadata={"flag": "--splits"})
    clip_model: str | None = None
    expert_keyframes: str | None = field(default=None, metadata={"choices": EXPERT_KEYFRAME_KINDS})

    def __post_init__(self) -> None:
        if self.expert_keyframes is not None and self.expert_keyframes not in EXPERT_KEYFRAME_KINDS:
            raise ConfigError(f"expert_keyframes: expected one of {', '.join(EXPERT_KEYFRAME_KINDS)}, "
                              f"got {self.expert_keyframes!r}")
        if self.grounder is None and self.clip_model is None:
            return  # nothing to check
        grounder_from_flags(self.grounder, self.clip_model)  # a clear error for --clip-model without a CLIP grounder

    def signature(self) -> str:
        """Compact JSON of the settings that change outcomes (recorded with every outcome; ``clip_model`` and
        ``expert_keyframes`` only when set, so outcomes recorded before they existed still match)."""
        optional = ("clip_model", "expert_keyframes")
        fields = {k: v for k, v in asdict(self).items() if k != "device" and not (k in optional and v is None)}
        return json.dumps(fields, sort_keys=True)
