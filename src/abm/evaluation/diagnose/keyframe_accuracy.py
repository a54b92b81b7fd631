"""The ``keyframe_accuracy`` diagnosis: offline keyframe accuracy of trained policies, per keyframe kind (the quick
check before rollouts; the measurement is :mod:`abm.evaluation.keyframe_accuracy`).

On evaluation scenes (the seeds of ``abm eval``) the expert is rolled out and each policy predicts at every expert
keyframe; position error, symmetry-aware rotation error and gripper agreement are summarised per kind. With
``steps`` the listed checkpoints of each run are scored too (the grasp error against training time); ``grounder``
overrides the checkpoints' grounder (``oracle``: the simulator's mask, so an error that stays is the policy's).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.evaluation.diagnose.request import DiagnosisRequest, write_json
from abm.evaluation.keyframe_accuracy import as_records, keyframe_errors, markdown, summarise
from abm.evaluation.runner import method_labels
from abm.grounding.config import grounder_from_flags
from abm.machine import describe_machine
from abm.policy import KeyframePolicy
from abm.policy.checkpoint import checkpoint_path

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class KeyframeAccuracy(DiagnosisRequest):
    """Score ``models`` at every expert keyframe of ``episodes`` evaluation scenes per task and split.

    Attributes:
        models: run folders, checkpoints or zoo files (each labelled as in ``abm eval``'s tables).
        tasks: the tasks whose scenes are scored.
        out: the JSON written (``None``: nothing written): ``machine``, ``episodes``, ``grounder``,
            ``checkpoints`` (label -> file), ``summary`` (rows of
            :func:`abm.evaluation.keyframe_accuracy.summarise`), ``errors`` (every prediction).
        splits: object splits.
        episodes: scenes per task and split (the seeds of ``abm eval``, repeat 0).
        resolution: camera pixels (as in training).
        steps: also score these checkpoint steps of every model (``LABEL@STEP``; a missing one is skipped).
        grounder: a grounder kind that replaces the checkpoints' (as ``abm eval --grounder``; ``None``: theirs).
        clip_model: CLIP weights of a ``clip`` or ``tracking`` grounder.
    """

    kind = "keyframe_accuracy"

    models: tuple[Path, ...]
    tasks: tuple[str, ...]
    out: Path | None = None
    splits: tuple[str, ...] = ("seen", "unseen")
    episodes: int = 10
    resolution: int = 128
    steps: tuple[int, ...] = ()
    grounder: str | None = None
    clip_model: str | None = None

    def policies(self) -> dict[str, Any]:
        """Label -> loaded :class:`abm.policy.KeyframePolicy` of every model (and of its ``steps``)."""
        grounder = grounder_from_flags(self.grounder, self.clip_model)
        labels = method_labels(self.models)
        policies = {}
        for run in self.models:
            name = labels[str(run)] + (f" [{self.grounder} grounder]" if self.grounder else "")
            policies[name] = KeyframePolicy.from_checkpoint(run, grounder=grounder)
            for step in self.steps:
                path = checkpoint_path(run, step)
                if path.is_file():
                    policies[f"{name}@{step}"] = KeyframePolicy.from_checkpoint(path, grounder=grounder)
                else:
                    log.warning("skipping %s: no such checkpoint", path)
        return policies

    def run(self) -> dict[str, Any]:
        """Score every policy, write :attr:`out` and return its content (the summary table is logged)."""
        policies = self.policies()
        start = time.perf_counter()
        errors = []
        for task in self.tasks:
            for split in self.splits:
                errors += keyframe_errors({k: p.act for k, p in policies.items()}, task, split, self.episodes,
                                          self.resolution)
        payload: dict[str, Any] = {
            "machine": describe_machine(), "episodes": self.episodes, "grounder": self.grounder or "checkpoint's",
            "checkpoints": {k: str(p.checkpoint_path) for k, p in policies.items()},
            "summary": summarise(errors), "errors": as_records(errors)}
        log.info("machine: %s; %d scenes per task and split (seeds as abm eval); %.0f s\n%s", payload["machine"],
                 self.episodes, time.perf_counter() - start, markdown(payload["summary"]))
        write_json(self.out, payload)
        return payload
