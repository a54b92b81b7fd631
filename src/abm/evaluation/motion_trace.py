"""Why rollouts stop: a policy's closed-loop keyframes traced step by step against the expert's plan.

``abm eval`` names one failure reason per episode (:func:`abm.evaluation.step_records.episode_failure`) and
keeps a record per step (:mod:`abm.evaluation.step_records`: the motion's status, the nearest expert keyframe);
"motion blocked" — the arm moved but ended more than 1 cm / 5 degrees from the predicted pose — says that
a motion stopped short, not why. :func:`trace_rollout` rolls a policy out on an
evaluation scene (closed loop, as ``abm eval`` does) and records, per step, the motion's status and how
far it ended from its target, next to the expert keyframe of the same index on the same scene (the
expert is rolled out first on a copy of the scene): the predicted pose's distance and height offset from
it, and whether the gripper and collision flags agree. :func:`summarise_traces` counts the statuses per
expert keyframe kind. ``benchmarks/motion_failures.py`` is the command line.

The expert comparison is by index: it is meaningful while the policy follows the expert's keyframe
sequence (it usually does: the tasks' keyframe kinds come in a fixed order), and ``expert_kind`` is
``""`` past the expert's last keyframe.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from abm.evaluation.keyframe_accuracy import score_keyframe
from abm.sim.env import make_env, run_expert
from abm.types import KeyframeAction, Observation

ActFn = Callable[[Observation, str, Mapping[int, str]], KeyframeAction]
"""``(observation, instruction, object_names) -> keyframe`` (e.g. :meth:`abm.policy.KeyframePolicy.act`)."""


@dataclass(frozen=True)
class StepTrace:
    """One executed keyframe of a closed-loop rollout.

    Attributes:
        seed: scene seed. index: keyframe index in the rollout (0-based).
        expert_kind: kind of the expert's keyframe of the same index (``""`` past its last one).
        status: the motion's status (reached, unreachable, blocked, collided).
        message: the motion's explanation (e.g. the error it stopped at, the geoms it touched).
        stop_error_cm: distance the TCP ended from the predicted pose, cm (NaN when nothing moved).
        expert_cm: predicted position's distance from the expert keyframe, cm (NaN without one).
        expert_dz_cm: predicted height minus the expert's, cm (negative: lower than the expert).
        expert_yaw_deg: symmetry-aware rotation error against the expert keyframe, degrees.
        gripper_agrees / collision_agrees: the predicted flags equal the expert's.
        success: the task was done after this step.
    """

    seed: int
    index: int
    expert_kind: str
    status: str
    message: str
    stop_error_cm: float
    expert_cm: float
    expert_dz_cm: float
    expert_yaw_deg: float
    gripper_agrees: bool
    collision_agrees: bool
    success: bool


def trace_rollout(act: ActFn, task: str, split: str, seed: int, resolution: int = 128,
                  max_steps: int = 8) -> list[StepTrace]:
    """Roll ``act`` out on one scene and trace every step against the expert's keyframes (see module doc).

    Args:
        act: the policy. task, split, seed: the scene (``abm eval``'s seeds come from
            :func:`abm.evaluation.results.eval_seed`). resolution: camera pixels. max_steps: keyframe budget.
    """
    with make_env(task, split, seed, resolution, max_steps=max_steps) as env:
        expert = [label for _, label in run_expert(env).steps]
        obs = env.reset()
        out: list[StepTrace] = []
        for index in range(max_steps):
            action = act(obs, env.instruction, env.object_names)
            obs, success, info = env.step(action)
            motion = info["motion"]
            label = expert[index] if index < len(expert) else None
            if label is None:
                dist = dz = yaw = float("nan")
                grip = coll = False
            else:
                dist, yaw, grip = score_keyframe(action, label)
                dz = 100.0 * float(action.position[2] - label.position[2])
                coll = action.ignore_collision == label.ignore_collision
            out.append(StepTrace(seed, index, label.kind if label else "", motion.status, motion.message,
                                 100.0 * float(motion.position_error), dist, dz, yaw, grip, coll, bool(success)))
            if info["done"]:
                break
    return out


def summarise_traces(traces: Iterable[StepTrace]) -> list[dict[str, Any]]:
    """Per expert keyframe kind: steps, count of each status, and for the stopped ones (blocked or
    unreachable) the median stop error, distance from the expert keyframe, height offset and yaw error (for the
    reached ones the distance and yaw error)."""
    by_kind: dict[str, list[StepTrace]] = {}
    for t in traces:
        by_kind.setdefault(t.expert_kind or "(past the expert)", []).append(t)
    rows = []
    for kind, steps in by_kind.items():
        stopped = [t for t in steps if t.status in ("blocked", "unreachable")]
        row: dict[str, Any] = {"kind": kind, "steps": len(steps)}
        for status in ("reached", "blocked", "unreachable", "collided"):
            row[status] = sum(t.status == status for t in steps)
        row["stopped_stop_error_cm"] = _median(t.stop_error_cm for t in stopped)
        row["stopped_expert_cm"] = _median(t.expert_cm for t in stopped)
        row["stopped_expert_dz_cm"] = _median(t.expert_dz_cm for t in stopped)
        row["stopped_yaw_deg"] = _median(t.expert_yaw_deg for t in stopped)
        reached = [t for t in steps if t.status == "reached"]
        row["reached_expert_cm"] = _median(t.expert_cm for t in reached)
        row["reached_yaw_deg"] = _median(t.expert_yaw_deg for t in reached)
        rows.append(row)
    return rows


def _median(values: Iterable[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return round(statistics.median(finite), 2) if finite else float("nan")


def markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    head = ("kind", "steps", "reached", "blocked", "unreachable", "collided", "stopped: stop error cm",
            "stopped: from expert cm", "stopped: dz cm", "stopped: yaw deg", "reached: from expert cm",
            "reached: yaw deg")
    keys = ("kind", "steps", "reached", "blocked", "unreachable", "collided", "stopped_stop_error_cm",
            "stopped_expert_cm", "stopped_expert_dz_cm", "stopped_yaw_deg", "reached_expert_cm", "reached_yaw_deg")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(r[k]) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def as_records(traces: Iterable[StepTrace]) -> list[dict[str, Any]]:
    return [asdict(t) for t in traces]
