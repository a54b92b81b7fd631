"""The ``destination_grounding`` diagnosis: how well a grounder finds the destination (the mask variants' second
mask, ``PolicyConfig.destination_mask``) beside the target X, per task and split.

For the first observation of evaluation scenes (held-out seeds: :func:`abm.evaluation.results.eval_seed` of
repeat 0, the seeds of ``abm eval``), each task's target X and its declared destination (``Task.destination``) are
grounded with the text as the policy reads it (X from the instruction's split, the destination from
:func:`abm.language.roles.instruction_destination`) and scored against the simulator's segmentation of the true
object (:func:`abm.grounding.metrics.score_mask`): point IoU, hit rate (the mask centre inside the object's
bounding box grown by 1 cm) and found rate. A task without a destination (take_off_pan) has target rows only. The
grounder is the CLIP grounder in its default configuration with the given CLIP (3-D proposals, as the paper-table
runs ground), or any grounder kind (the oracle grounds both exactly, IoU 1, by construction). It measures the
grounder, not a policy: an experiment runs it once, for its CLIP (``diagnose: destination_grounding:``).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from abm.evaluation.diagnose.request import DiagnosisRequest
from abm.evaluation.results import eval_seed
from abm.geometry import Workspace, fuse_cameras
from abm.grounding.config import build_grounder, grounder_from_flags
from abm.grounding.grounders import Grounder, target_point_mask
from abm.grounding.metrics import score_mask
from abm.language.roles import instruction_destination, split_instruction
from abm.machine import describe_machine
from abm.sim.env import make_env
from abm.sim.tasks import TASKS

log = logging.getLogger(__name__)

#: the tasks with a destination that ``benchmarks/destination_grounding.py`` measures by default
DESTINATION_TASKS = ("pick_block", "place_food", "place_wine", "put_in_shelf", "water_plants", "close_jar",
                     "insert_peg", "put_in_container")


def point_iou(mask: np.ndarray, truth: np.ndarray) -> float:
    """Point IoU of a ``(N,)`` mask (values > 0.5 selected) and the ``(N,)`` true points (NaN when both are
    empty)."""
    selected, true = np.asarray(mask).reshape(-1) > 0.5, np.asarray(truth, bool).reshape(-1)
    union = int((selected | true).sum())
    return int((selected & true).sum()) / union if union else math.nan


def scene_scores(grounder: Grounder, task: str, split: str, episode: int, resolution: int
                 ) -> dict[str, tuple[float, bool, bool]]:
    """Role (``target``, ``destination``) -> ``(IoU, hit, found)`` of the first observation of one evaluation
    scene (a role the scene's instruction or task does not name is left out)."""
    with make_env(task, split, eval_seed(0, episode), resolution) as env:
        obs = env.reset()
        names, truth_names, instruction = env.object_names, env.target_names, env.instruction
    cloud = fuse_cameras(obs, Workspace())
    queries = {"target": (split_instruction(instruction, names)[0], truth_names[0]),
               "destination": (instruction_destination(instruction), TASKS[task].destination_name(truth_names))}
    scores = {}
    for role, (text, true_name) in queries.items():
        if text is None or true_name is None:
            continue
        truth = target_point_mask(obs, cloud, true_name, names)
        field = grounder.ground(obs, cloud, text, names)
        score = score_mask(cloud.xyz, field.mask, truth, field.found)
        scores[role] = (point_iou(field.mask, truth), score.hit, score.found)
    return scores


def grounding_rows(grounder: Grounder, tasks: Sequence[str], splits: Sequence[str], episodes: int,
                   resolution: int) -> list[dict[str, Any]]:
    """One row per task, split and role grounded: ``task``, ``split``, ``object`` (the role), ``n`` (scenes),
    ``iou`` (mean point IoU over the scenes where either mask is non-empty; NaN if none), ``hit_rate`` and
    ``found_rate`` (fractions of the scenes), in task, split, role order."""
    found: dict[tuple[str, str, str], list[tuple[float, bool, bool]]] = defaultdict(list)
    for task in tasks:
        for split in splits:
            for episode in range(episodes):
                for role, score in scene_scores(grounder, task, split, episode, resolution).items():
                    found[(task, split, role)].append(score)
    rows = []
    for (task, split, role), items in found.items():
        ious = [v for v, _, _ in items if not math.isnan(v)]
        rows.append({"task": task, "split": split, "object": role, "n": len(items),
                     "iou": float(np.mean(ious)) if ious else math.nan,
                     "hit_rate": float(np.mean([hit for _, hit, _ in items])),
                     "found_rate": float(np.mean([ok for _, _, ok in items]))})
    return rows


def markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as the benchmark prints them (a markdown table, one row per task, split and role)."""
    lines = ["| task | split | object | n | IoU | hit rate | found rate |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['task']} | {r['split']} | {r['object']} | {r['n']} | {r['iou']:.2f} | {r['hit_rate']:.2f} | "
              f"{r['found_rate']:.2f} |" for r in rows]
    return "\n".join(lines)


@dataclass(frozen=True)
class DestinationGrounding(DiagnosisRequest):
    """Ground the target and the destination of ``episodes`` evaluation scenes per task and split.

    Attributes:
        clip_model: the CLIP weights of the grounder (a folder or hub name; ``None``: a kind without CLIP).
        out: the JSON written (``None``: nothing written): the rows of :func:`grounding_rows`, a list (the
            format of ``docs/results/destination_grounding.json``).
        tasks: the tasks measured.
        splits: object splits.
        episodes: scenes per task and split (the seeds of ``abm eval``, repeat 0; first observation).
        resolution: camera pixels.
        grounder: the grounder kind measured (``clip``: its default configuration with ``clip_model``).
        device: the CLIP's device.
    """

    kind = "destination_grounding"

    clip_model: str | None
    out: Path | None = None
    tasks: tuple[str, ...] = DESTINATION_TASKS
    splits: tuple[str, ...] = ("seen", "unseen")
    episodes: int = 5
    resolution: int = 128
    grounder: str = "clip"
    device: str = "cpu"

    def run(self) -> list[dict[str, Any]]:
        """Measure, write :attr:`out` and return its rows (the table is logged)."""
        config = grounder_from_flags(self.grounder, self.clip_model, self.device if self.clip_model else None)
        start = time.perf_counter()
        rows = grounding_rows(build_grounder(config), self.tasks, self.splits, self.episodes, self.resolution)
        log.info("machine: %s; grounder %s %s, %d scenes per task and split (first observation); %.0f s\n%s",
                 describe_machine(), self.grounder, self.clip_model or "", self.episodes,
                 time.perf_counter() - start, markdown(rows))
        if self.out is not None:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.out.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
        return rows
