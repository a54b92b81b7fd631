"""The ``rotation_fit`` diagnosis: how well a policy fits the rotation labels of its own training keyframes, per task
and keyframe kind (the measurement is :mod:`abm.evaluation.rotation_fit`).

Every keyframe of the demonstrations (the tasks and seen split a run trained on) is predicted teacher-forced, as in
training, without and with the training augmentation; a row gives the mean cross-entropy (nats) of the roll, pitch
and yaw bins per task and keyframe kind, beside the yaw's chance line for the keyframes' symmetry (ln 36 two-fold,
ln 18 four-fold, 0 round) and the prior of a model that knows only the task and the kind. A probe's learning curve
collects the rows of several arms and steps in its JSON's ``fit`` list (:func:`add_to_probe`).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from abm.data.episode_store import EpisodeStore
from abm.data.keyframes import EpisodeSource, KeyframeDataset
from abm.errors import ConfigError, DataError
from abm.evaluation.diagnose.request import DiagnosisRequest, write_json
from abm.evaluation.rotation_fit import FitRow, rotation_fit
from abm.machine import describe_machine
from abm.policy import KeyframePolicy

log = logging.getLogger(__name__)

Rows = list[tuple[bool, FitRow]]
"""Fit rows with the augmentation flag they were measured with."""


@dataclass(frozen=True)
class RotationFit(DiagnosisRequest):
    """Fit rows of one model on its training keyframes, augmentation off then on.

    Attributes:
        model: a run folder, checkpoint or zoo file.
        data: the episode store the run trained on.
        tasks: the tasks scored (``None``: every task in ``data``).
        out: the rows written as JSON (``[{augment, task, keyframe, keyframes, cross_entropy, yaw_chance,
            yaw_prior}, ...]``; ``None``: not written).
        probe: a probe's JSON whose ``fit`` list gets the rows as ``arm`` at ``step`` (:func:`add_to_probe`).
        arm: with ``probe``: the arm's name (``single-stage``, ``two-stage``, ...).
        step: with ``probe``: the checkpoint's training step.
    """

    kind = "rotation_fit"

    model: Path
    data: Path
    tasks: tuple[str, ...] | None = None
    out: Path | None = None
    probe: Path | None = None
    arm: str | None = None
    step: int | None = None

    def __post_init__(self) -> None:
        if self.probe is not None and (self.arm is None or self.step is None):
            raise ConfigError("a rotation fit into a probe needs its arm and step")

    def measure(self) -> Rows:
        """Fit rows of :attr:`model` on its training keyframes, augmentation off then on.

        Raises:
            DataError: ``data`` holds no seen episode of the tasks.
        """
        torch.set_num_threads(1)
        started = time.perf_counter()
        policy = KeyframePolicy.from_checkpoint(self.model).eval()
        store = EpisodeStore(self.data)
        indices = store.select(tasks=list(self.tasks) if self.tasks else None, splits=["seen"])
        if not indices:
            raise DataError(f"no seen episodes of {list(self.tasks) if self.tasks else 'any task'} in {self.data}")
        options = policy.sample_options()
        rows: Rows = []
        for augment in (False, True):
            dataset = KeyframeDataset(EpisodeSource(store, indices), policy.workspace, policy.grounder_config,
                                      split=options["split"], mask=options["mask"], features=options["features"],
                                      destination=options["destination"], augment=augment, seed=0)
            rows += [(augment, r) for r in rotation_fit(policy, dataset)]
        log.info("machine: %s; %s on %d episodes of %s; %.0f s", describe_machine(), self.model, len(indices),
                 self.data, time.perf_counter() - started)
        return rows

    def write(self, rows: Rows) -> list[dict[str, Any]]:
        """Write ``rows`` to :attr:`out` and into :attr:`probe` (each when set); returns them as JSON records."""
        records = [{"augment": a, **asdict(r)} for a, r in rows]
        write_json(self.out, records, newline=True)
        if self.probe is not None:
            assert self.arm is not None and self.step is not None  # __post_init__
            add_to_probe(self.probe, self.arm, self.step, rows)
        return records

    def run(self) -> list[dict[str, Any]]:
        """Measure, write :attr:`out` (and the probe's ``fit`` rows) and return the rows (the table is logged)."""
        rows = self.measure()
        log.info("%s", table(rows))
        return self.write(rows)


def read_rows(path: Path) -> Rows:
    """The rows a :class:`RotationFit` wrote to its ``out``."""
    saved = json.loads(path.read_text())
    return [(r.pop("augment"), FitRow(**{**r, "cross_entropy": tuple(r["cross_entropy"])})) for r in saved]


def table(rows: Rows) -> str:
    """Markdown table of fit rows (augmentation flag, row)."""
    lines = ["| augmentation | task | keyframe | keyframes | x (roll) | y (pitch) | z (yaw) | yaw chance | yaw prior |",
             "|---|---|---|---|---|---|---|---|---|"]
    for augment, r in rows:
        x, y, z = r.cross_entropy
        lines.append(f"| {'on' if augment else 'off'} | {r.task} | {r.keyframe} | {r.keyframes} | {x:.2f} | {y:.2f} "
                     f"| {z:.2f} | {r.yaw_chance:.2f} | {r.yaw_prior:.2f} |")
    return "\n".join(lines)


def add_to_probe(path: Path, arm: str, step: int, rows: Rows) -> None:
    """Put fit rows into a probe's JSON ``fit`` list as ``{arm, step, augment, task, keyframe, keyframes, yaw_ce,
    roll_ce, pitch_ce, yaw_chance, yaw_prior}``, replacing earlier rows of the same arm and step."""
    probe = json.loads(path.read_text()) if path.exists() else {}
    fit = [r for r in probe.get("fit", []) if (r["arm"], r["step"]) != (arm, step)]
    fit += [{"arm": arm, "step": step, "augment": a, "task": r.task, "keyframe": r.keyframe,
             "keyframes": r.keyframes, "yaw_ce": round(r.yaw, 3), "roll_ce": round(r.cross_entropy[0], 3),
             "pitch_ce": round(r.cross_entropy[1], 3), "yaw_chance": round(r.yaw_chance, 3),
             "yaw_prior": round(r.yaw_prior, 3)} for a, r in rows]
    fit.sort(key=lambda r: (r["arm"], r["step"], r["augment"]))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"fit": fit, "accuracy": probe.get("accuracy", []),
                                "rollouts": probe.get("rollouts", [])}, indent=1) + "\n")
