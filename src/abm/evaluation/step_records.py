"""What every step of an evaluation rollout did, and the failure rule that reads those steps.

``abm eval`` stores one :class:`StepRecord` per executed keyframe in each outcome (``step_records``, compact
JSON: :meth:`StepRecord.to_json`): the keyframe the policy predicted, how the arm's motion ended, whether the
gripper then held the object the task must hold (:meth:`abm.sim.tasks.Task.held_object`), the nearest keyframe
of the scripted expert on the same scene and how far it is, and the grounding decision of a mask policy. The
expert's keyframes are computed once per episode, after the rollout, in the rollout's scene reset to its first
state (:func:`expert_keyframes`), so they never touch what the rollout saw (its RNGs, its physics).

A failed rollout's reason (:func:`episode_failure`) is the first stop the policy did not recover from, in step
order, else ``grasp missed`` (the object was never held) or ``timeout``. A stopped step (motion ``blocked``,
``unreachable`` or ``collided``) is *recovered* (:func:`recovered`) when a later step

1. re-did it: reached (status ``reached``) a pose within :data:`RECOVERY_CM` and :data:`RECOVERY_DEG` (the
   parallel gripper's 180° turn counted as the same) of the stopped step's pose, with the same gripper command;
2. restored the holding: the object was held before the stopped step, not after it, and is held again after
   the later step; or
3. completed the grasp: the stopped step closed the gripper on nothing held, and the object is held after it
   (a collided grasp that got the object) or after a later step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from abm.geometry.rotations import GRIPPER_SYMMETRY, quat_to_matrix, symmetric_angle_deg
from abm.types import KeyframeAction

RECOVERY_CM = 2.0
"""Position (cm) within which a later reached keyframe re-does a stopped one (a grasp's tolerance,
:data:`abm.evaluation.keyframe_accuracy.GRASP_TOLERANCE_CM`)."""
RECOVERY_DEG = 15.0
"""Rotation (degrees, the gripper's 180° turn counted as the same) within which a later keyframe re-does a
stopped one."""
STOP_FAILURES = {"unreachable": "IK unreachable", "blocked": "motion blocked", "collided": "collision"}
"""Motion status of a stopped step -> the failure reason it gives when the policy does not recover."""


@dataclass(frozen=True)
class StepRecord:
    """One executed keyframe of an evaluation rollout.

    Attributes:
        position: predicted TCP position, ``(3,)`` metres, world frame.
        quaternion: predicted orientation ``(x, y, z, w)``.
        gripper_open: the predicted gripper command (open).
        motion: the motion's status: ``reached``, ``blocked``, ``unreachable`` or ``collided``.
        held: whether the gripper held the task's held object after the step.
        stop_cm: how far (cm) the TCP ended from the predicted pose (``None`` when the arm did not move).
        ignore_collision: the predicted planner flag (straight-line motion).
        expert_kind: kind of the expert keyframe nearest the prediction in position (``""``: no expert keyframe).
        expert_index: that keyframe's index in the expert's sequence (``-1``: none).
        expert_cm: the prediction's distance from it, cm.
        expert_deg: the prediction's rotation error against it, degrees (the label's symmetry counted).
        grounding: a mask policy's target decision on the step's mask (``found``, ``confidence``, ``target``,
            ``reason``: :func:`abm.grounding.decision.decide_target`); ``None`` for variants without a mask.
        substituted: the kind of the expert keyframe executed instead of the prediction (``move`` under
            ``abm eval --expert-keyframes move``: :mod:`abm.evaluation.expert_move`; ``""``: the prediction ran).
            ``position`` and ``quaternion`` are then the executed (expert's) keyframe's.
        policy_pose: the policy's own prediction of a substituted step, ``(x, y, z, qx, qy, qz, qw)``.
    """

    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    gripper_open: bool
    motion: str
    held: bool
    stop_cm: float | None = None
    ignore_collision: bool = False
    expert_kind: str = ""
    expert_index: int = -1
    expert_cm: float | None = None
    expert_deg: float | None = None
    grounding: dict[str, Any] | None = field(default=None)
    substituted: str = ""
    policy_pose: tuple[float, ...] | None = None

    @property
    def yaw_deg(self) -> float:
        """World yaw (degrees) of the predicted finger axis (the gripper's y axis)."""
        rot = quat_to_matrix(np.asarray(self.quaternion, np.float64))
        return math.degrees(math.atan2(rot[1, 1], rot[0, 1]))

    def to_json(self) -> dict[str, Any]:
        """The compact JSON form (the keys of docs/evaluation.md's schema): positions to 0.1 mm, quaternions to
        4 decimals, distances and angles to 0.1 cm / degree; ``yaw`` is :attr:`yaw_deg`, derived."""
        record: dict[str, Any] = {
            "pos": [round(float(v), 4) for v in self.position],
            "quat": [round(float(v), 4) for v in self.quaternion],
            "yaw": round(self.yaw_deg, 1),
            "open": self.gripper_open, "straight": self.ignore_collision,
            "motion": self.motion, "stop_cm": _rounded(self.stop_cm), "held": self.held,
            "expert": self.expert_kind, "expert_i": self.expert_index,
            "expert_cm": _rounded(self.expert_cm), "expert_deg": _rounded(self.expert_deg),
        }
        if self.grounding is not None:
            record["grounding"] = self.grounding
        if self.substituted:
            record["substituted"] = self.substituted
            if self.policy_pose is not None:
                record["policy_pos"] = [round(float(v), 4) for v in self.policy_pose[:3]]
                record["policy_quat"] = [round(float(v), 4) for v in self.policy_pose[3:]]
        return record

    @classmethod
    def from_json(cls, record: Mapping[str, Any]) -> StepRecord:
        """The record :meth:`to_json` wrote (``yaw`` is recomputed from the quaternion)."""
        pos, quat = record["pos"], record["quat"]
        return cls((pos[0], pos[1], pos[2]), (quat[0], quat[1], quat[2], quat[3]), bool(record["open"]),
                   str(record["motion"]), bool(record["held"]), record.get("stop_cm"),
                   bool(record.get("straight", False)), str(record.get("expert", "")),
                   int(record.get("expert_i", -1)), record.get("expert_cm"), record.get("expert_deg"),
                   record.get("grounding"), str(record.get("substituted", "")),
                   (*record["policy_pos"], *record["policy_quat"]) if "policy_pos" in record else None)


def _rounded(value: float | None, digits: int = 1) -> float | None:
    """``value`` rounded, ``None`` for ``None`` or NaN (JSON has no NaN)."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), digits)


def nearest_expert(action: KeyframeAction, expert: Sequence[KeyframeAction]) -> tuple[int, float, float]:
    """``(index, distance cm, rotation error deg)`` of the expert keyframe nearest ``action`` in position (the
    first of equals); ``(-1, nan, nan)`` without expert keyframes. The rotation error counts the label's
    symmetry (:attr:`abm.types.KeyframeAction.symmetry`)."""
    if not expert:
        return -1, math.nan, math.nan
    distances = [float(np.linalg.norm(action.position - label.position)) for label in expert]
    index = int(np.argmin(distances))
    label = expert[index]
    return index, 100.0 * distances[index], symmetric_angle_deg(action.quaternion, label.quaternion, label.symmetry)


def step_record(action: KeyframeAction, motion: str, held: bool, stop_error_m: float,
                expert: Sequence[KeyframeAction], grounding: dict[str, Any] | None = None,
                predicted: KeyframeAction | None = None) -> StepRecord:
    """The record of one executed keyframe: ``action`` executed, its motion's ``motion`` status ending
    ``stop_error_m`` (m, NaN: did not move) from its pose, ``held`` after it, against the ``expert``'s
    keyframes of the same scene (:func:`nearest_expert`); ``predicted``: the policy's own keyframe when an expert
    keyframe (``action``, of its ``kind``) was executed instead (:mod:`abm.evaluation.expert_move`)."""
    index, cm, deg = nearest_expert(action, expert)
    pos, quat = action.position, action.quaternion
    policy_pose = None if predicted is None else (*map(float, predicted.position), *map(float, predicted.quaternion))
    return StepRecord((float(pos[0]), float(pos[1]), float(pos[2])),
                      (float(quat[0]), float(quat[1]), float(quat[2]), float(quat[3])),
                      action.gripper_open, motion, held, 100.0 * stop_error_m, action.ignore_collision,
                      expert[index].kind if index >= 0 else "", index, cm, deg, grounding,
                      action.kind if predicted is not None else "", policy_pose)


def _redoes(later: StepRecord, stopped: StepRecord) -> bool:
    """Whether ``later`` reached a pose within the recovery tolerance of ``stopped``'s, same gripper command."""
    if later.motion != "reached" or later.gripper_open != stopped.gripper_open:
        return False
    cm = 100.0 * float(np.linalg.norm(np.subtract(later.position, stopped.position)))
    deg = symmetric_angle_deg(np.asarray(later.quaternion), np.asarray(stopped.quaternion), GRIPPER_SYMMETRY)
    return cm <= RECOVERY_CM and deg <= RECOVERY_DEG


def recovered(steps: Sequence[StepRecord], index: int) -> bool:
    """Whether the policy recovered from the stop at ``steps[index]`` (the three ways of the module doc)."""
    stopped, later = steps[index], steps[index + 1:]
    if any(_redoes(step, stopped) for step in later):
        return True
    held_before = steps[index - 1].held if index > 0 else False
    held_later = any(step.held for step in later)
    if held_before and not stopped.held and held_later:
        return True
    return not held_before and not stopped.gripper_open and (stopped.held or held_later)


def episode_failure(success: bool, error: str, steps: Sequence[StepRecord]) -> str:
    """Why a rollout failed (``""`` when it succeeded): ``crashed`` when it raised, else the reason of the first
    stop not :func:`recovered` from (:data:`STOP_FAILURES`), else ``timeout`` when the held object was held at
    some step and ``grasp missed`` when it never was."""
    if success:
        return ""
    if error:
        return "crashed"
    for index, step in enumerate(steps):
        if step.motion in STOP_FAILURES and not recovered(steps, index):
            return STOP_FAILURES[step.motion]
    return "timeout" if any(step.held for step in steps) else "grasp missed"


def expert_keyframes(env: Any) -> tuple[KeyframeAction, ...]:
    """The scripted expert's keyframes on ``env``'s scene (a :class:`abm.sim.env.TaskEnv`), as a demonstration
    labels them (:func:`abm.sim.env.executed_action`), up to its last executed one (an expert motion that stops
    ends the sequence, as in :func:`abm.sim.env.run_expert`).

    The simulator is reset to the scene's first state (without rendering) and the expert run in it: call it once
    the rollout in ``env`` is over, so it touches nothing the rollout saw (the expert draws from no global RNG).
    """
    from abm.sim.arm_control import STOPPED  # mujoco (optional `sim` extra)
    from abm.sim.env import executed_action  # mujoco (optional `sim` extra)

    sim = env.sim
    if sim is None:
        env.reset()
        sim = env.sim
    sim.reset()
    labels: list[KeyframeAction] = []
    for action in env.expert_actions():
        motion = sim.execute(action)
        labels.append(executed_action(action, motion.flipped))
        if motion.status in STOPPED:
            break
    return tuple(labels)
