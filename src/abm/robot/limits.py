"""Safety limits checked before any motion: a keyframe outside them is refused and nothing moves."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from abm.types import KeyframeAction


class LimitError(ValueError):
    """A predicted keyframe violates the robot's motion limits (nothing was moved)."""


@dataclass(frozen=True)
class MotionLimits:
    """Where and how far the arm may move in one keyframe.

    Attributes:
        workspace_lower / workspace_upper: ``(3,)`` corners of the allowed box for the tool centre point,
            in metres in the robot base frame.
        max_step_m: largest distance between the current and the target tool-centre position.
        max_tilt_deg: largest angle between the gripper's approach axis (its +z) and straight down.
    """

    workspace_lower: tuple[float, float, float] = (0.2, -0.45, -0.02)
    workspace_upper: tuple[float, float, float] = (0.85, 0.45, 0.6)
    max_step_m: float = 0.6
    max_tilt_deg: float = 90.0

    def check(self, current_pose: np.ndarray, action: KeyframeAction) -> None:
        """Raise :class:`LimitError` naming the violated limit and by how much."""
        pos = np.asarray(action.position, np.float64)
        lo, hi = np.asarray(self.workspace_lower), np.asarray(self.workspace_upper)
        if np.any(pos < lo) or np.any(pos > hi):
            raise LimitError(f"target position {np.round(pos, 3).tolist()} m is outside the workspace box "
                             f"{lo.tolist()}..{hi.tolist()}")
        step = float(np.linalg.norm(pos - np.asarray(current_pose)[:3, 3]))
        if step > self.max_step_m:
            raise LimitError(f"a {step:.3f} m move exceeds max_step_m {self.max_step_m}")
        down = action.matrix[:3, 2] @ np.array([0.0, 0.0, -1.0])
        tilt = float(np.degrees(np.arccos(np.clip(down, -1.0, 1.0))))
        if tilt > self.max_tilt_deg:
            raise LimitError(f"gripper tilted {tilt:.0f} deg from straight down exceeds max_tilt_deg "
                             f"{self.max_tilt_deg}")
