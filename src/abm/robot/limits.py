"""Safety limits checked before any motion: a keyframe outside them is refused and nothing moves."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from abm.errors import ConfigError, RefusedError
from abm.schema import Field, check_mapping, number, vector
from abm.types import KeyframeAction

# The declared schema of the ``limits`` section (and of :class:`MotionLimits` itself): finite numbers only,
# so ``.nan`` or ``.inf`` can never switch a check off.
LIMITS_SCHEMA = {
    "workspace_lower": Field(vector(3)),
    "workspace_upper": Field(vector(3)),
    "max_step_m": Field(number(0.0, low_open=True)),
    "max_tilt_deg": Field(number(0.0, 180.0, low_open=True)),
}


class LimitError(RefusedError):
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

    def __post_init__(self) -> None:
        """Refuse limits that would not limit: non-finite numbers, wrong shapes, an empty box, steps <= 0."""
        values = check_mapping("motion limits", "", dataclasses.asdict(self), LIMITS_SCHEMA)
        for key, value in values.items():
            object.__setattr__(self, key, value)
        lo, hi = np.asarray(self.workspace_lower), np.asarray(self.workspace_upper)
        if np.any(lo >= hi):
            raise ConfigError(f"motion limits: workspace_lower {list(self.workspace_lower)} must be below "
                              f"workspace_upper {list(self.workspace_upper)} on every axis")

    def check(self, current_pose: np.ndarray, action: KeyframeAction) -> None:
        """Raise :class:`LimitError` naming the violated limit and by how much."""
        pos = np.asarray(action.position, np.float64)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(action.matrix))):
            raise LimitError(f"target pose is not finite (position {pos.tolist()})")
        lo, hi = np.asarray(self.workspace_lower), np.asarray(self.workspace_upper)
        if np.any(pos < lo) or np.any(pos > hi):
            raise LimitError(f"target position {np.round(pos, 3).tolist()} m is outside the workspace box "
                             f"{lo.tolist()}..{hi.tolist()}")
        step = float(np.linalg.norm(pos - np.asarray(current_pose)[:3, 3]))
        if not step <= self.max_step_m:  # also refuses a NaN distance (a non-finite current pose)
            raise LimitError(f"a {step:.3f} m move exceeds max_step_m {self.max_step_m}")
        down = action.matrix[:3, 2] @ np.array([0.0, 0.0, -1.0])
        tilt = float(np.degrees(np.arccos(np.clip(down, -1.0, 1.0))))
        if not tilt <= self.max_tilt_deg:
            raise LimitError(f"gripper tilted {tilt:.0f} deg from straight down exceeds max_tilt_deg "
                             f"{self.max_tilt_deg}")
