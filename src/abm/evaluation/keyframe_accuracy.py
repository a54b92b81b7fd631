"""Offline keyframe accuracy: a policy's keyframes against the scripted expert's, kind by kind.

The expert is rolled out on an evaluation scene; at every expert keyframe the policy predicts from the
same observation (teacher forcing: the rollout follows the expert, not the policy), and the prediction
is scored against the expert's label:

* position error (cm);
* rotation error (degrees), the smallest over the label's symmetric equivalents — the parallel
  gripper's 180-degree turn, and a square object's 90-degree or a round object's any turn (the label's
  :attr:`abm.types.KeyframeAction.symmetry`) — so a grasp that is as good as the label scores 0;
* whether the gripper open/close state agrees.

Rows are grouped by keyframe kind (approach, grasp, lift, move, place, retreat, pour), so one can see
which part of a task a checkpoint has learned. It is the quick check of a checkpoint before rollouts
(the ``keyframe_accuracy`` diagnosis, :mod:`abm.evaluation.diagnose.keyframe_accuracy`). :func:`skill_text_probe`
asks whether a mask policy's keyframe follows its skill text (the ``skill_text`` diagnosis).
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from abm.evaluation.results import eval_seed
from abm.geometry import ROUND_SYMMETRY, symmetric_angle_deg
from abm.language.roles import split_roles
from abm.sim.env import make_env, run_expert
from abm.types import KeyframeAction, Observation

ActFn = Callable[[Observation, str, Mapping[int, str]], KeyframeAction]
"""``(observation, instruction, object_names) -> keyframe`` (e.g. :meth:`abm.policy.KeyframePolicy.act`)."""

GRASP_TOLERANCE_CM = 2.0
"""Position error a grasp tolerates (measured on pick_block by perturbing expert keyframes)."""


def yaw_chance_deg(symmetry: int) -> float:
    """Median rotation error (degrees) of a yaw drawn at random about the gripper axis, scored against a label
    of this symmetry: uniform over [0, 180° / symmetry], so 45° for the parallel gripper's two-fold turn,
    22.5° for a square object's four-fold one, and 0 for a round object (any yaw is right)."""
    if symmetry == ROUND_SYMMETRY:
        return 0.0
    return 90.0 / max(symmetry, 1)


@dataclass(frozen=True)
class KeyframeDeviation:
    """One prediction against one expert keyframe."""

    method: str
    task: str
    split: str
    seed: int
    index: int
    kind: str
    position_cm: float
    rotation_deg: float
    gripper_agrees: bool
    symmetry: int = 2


def score_keyframe(pred: KeyframeAction, label: KeyframeAction) -> tuple[float, float, bool]:
    """``(position error cm, symmetry-aware rotation error deg, gripper agrees)`` of ``pred``."""
    pos = 100.0 * float(np.linalg.norm(pred.position - label.position))
    rot = symmetric_angle_deg(pred.quaternion, label.quaternion, label.symmetry)
    return pos, rot, pred.gripper_open == label.gripper_open


def keyframe_errors(
    policies: Mapping[str, ActFn],
    task: str,
    split: str,
    episodes: int,
    resolution: int = 128,
) -> list[KeyframeDeviation]:
    """Score every policy at every expert keyframe of ``episodes`` evaluation scenes.

    Scenes use the evaluation seeds of ``abm eval`` (repeat 0), so numbers line up with rollouts.
    Scenes whose expert fails are skipped.
    """
    out: list[KeyframeDeviation] = []
    for ep in range(episodes):
        seed = eval_seed(0, ep)
        with make_env(task, split, seed, resolution) as env:
            episode = run_expert(env)
            if not episode.success:
                continue
            for index, (obs, label) in enumerate(episode.steps):
                for name, act in policies.items():
                    pos, rot, grip = score_keyframe(act(obs, env.instruction, env.object_names), label)
                    out.append(KeyframeDeviation(name, task, split, seed, index, label.kind, pos, rot, grip,
                                                 label.symmetry))
    return out


def summarise(errors: Iterable[KeyframeDeviation]) -> list[dict[str, object]]:
    """One row per (method, task, split, kind): medians, fraction within the grasp tolerance, counts, and the
    median over its keyframes of a random yaw's error (``yaw_chance_deg``, :func:`yaw_chance_deg` of each
    label's symmetry), the chance line of ``rotation_deg_median``."""
    groups: dict[tuple[str, str, str, str], list[KeyframeDeviation]] = {}
    for e in errors:
        groups.setdefault((e.method, e.task, e.split, e.kind), []).append(e)
    rows = []
    for (method, task, split, kind), es in groups.items():
        pos = [e.position_cm for e in es]
        rows.append({
            "method": method, "task": task, "split": split, "kind": kind, "n": len(es),
            "position_cm_median": statistics.median(pos),
            "within_grasp_tolerance": sum(p <= GRASP_TOLERANCE_CM for p in pos) / len(es),
            "rotation_deg_median": statistics.median(e.rotation_deg for e in es),
            "gripper_agrees": sum(e.gripper_agrees for e in es) / len(es),
            "yaw_chance_deg": statistics.median(yaw_chance_deg(e.symmetry) for e in es),
        })
    return rows


def markdown(rows: Sequence[Mapping[str, Any]], kinds: Sequence[str] | None = None) -> str:
    """A markdown table of :func:`summarise` rows (optionally only some kinds)."""
    lines = [f"| method | task | split | keyframe | n | position error cm (median) | within "
             f"{GRASP_TOLERANCE_CM:g} cm | rotation error ° (median, symmetry-aware) | gripper agrees |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if kinds is not None and r["kind"] not in kinds:
            continue
        lines.append(f"| {r['method']} | {r['task']} | {r['split']} | {r['kind']} | {r['n']} | "
                     f"{r['position_cm_median']:.1f} | {100 * r['within_grasp_tolerance']:.0f} % | "
                     f"{r['rotation_deg_median']:.0f} | {100 * r['gripper_agrees']:.0f} % |")
    return "\n".join(lines)


def as_records(errors: Iterable[KeyframeDeviation]) -> list[dict[str, object]]:
    """Plain dicts (for JSON)."""
    return [asdict(e) for e in errors]


def task_skills(tasks: Sequence[str]) -> dict[str, str]:
    """``skill text -> task`` (the first task with that text) from each task's first evaluation scene."""
    out: dict[str, str] = {}
    for task in tasks:
        with make_env(task, "seen", eval_seed(0, 0), 16) as env:
            _, skill = split_roles(env.instruction, env.object_names)
        out.setdefault(skill, task)
    return out


def skill_text_probe(act: ActFn, task: str, split: str, episodes: int, kind: str, skills: Sequence[str],
                     resolution: int = 128) -> list[dict[str, object]]:
    """Does a mask policy's ``kind`` keyframe follow its skill text?

    Teacher-forced like :func:`keyframe_errors`: at every expert keyframe of that kind the policy predicts
    once with the scene's instruction and once per skill text in ``skills``, worded about the scene's
    target (``"take X off the frypan"`` -> ``"take the wine bottle off the frypan"``). One row per skill
    text: ``position_cm_median`` against the expert's label, ``moved_cm_median`` from the prediction with
    the scene's own instruction, and ``own`` (the scene's own skill text). A policy that reads its text
    moves when the text changes.
    """
    errors: dict[str, list[float]] = {s: [] for s in skills}
    moved: dict[str, list[float]] = {s: [] for s in skills}
    own_skill = None
    for ep in range(episodes):
        with make_env(task, split, eval_seed(0, ep), resolution) as env:
            episode = run_expert(env)
            if not episode.success:
                continue
            targets, own_skill = split_roles(env.instruction, env.object_names)
            for obs, label in episode.steps:
                if label.kind != kind:
                    continue
                own = act(obs, env.instruction, env.object_names).position
                for skill in skills:
                    pred = act(obs, skill.replace("X", f"the {targets[0]}"), env.object_names).position
                    errors[skill].append(100.0 * float(np.linalg.norm(pred - label.position)))
                    moved[skill].append(100.0 * float(np.linalg.norm(pred - own)))
    if not any(errors.values()):
        raise ValueError(f"no successful expert rollout of {task} ({split}) with a {kind!r} keyframe in "
                         f"{episodes} scenes")
    return [{"skill": s, "own": s == own_skill, "n": len(errors[s]),
             "position_cm_median": statistics.median(errors[s]), "moved_cm_median": statistics.median(moved[s])}
            for s in skills]
