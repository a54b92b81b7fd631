"""The workspace: a fixed axis-aligned cube in the robot-base (world) frame.

Points outside the cube are dropped before rendering, and the renderer's virtual views and the
policy's translation heatmaps cover exactly this cube.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# Robot base at the origin, table top at z = 0; the cube reaches 1 m in front of the base and
# 15 cm below the table top so the table surface is always inside.
DEFAULT_CENTER = (0.5, 0.0, 0.35)
DEFAULT_SIZE = 1.0


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned cube.

    Attributes:
        center: ``(x, y, z)`` of the cube centre in metres (world frame).
        size: edge length in metres.
    """

    center: tuple[float, float, float] = DEFAULT_CENTER
    size: float = DEFAULT_SIZE

    def __post_init__(self) -> None:
        if len(self.center) != 3:
            raise ValueError(f"Workspace.center must have 3 values, got {self.center}")
        if not self.size > 0:
            raise ValueError(f"Workspace.size must be positive, got {self.size}")
        object.__setattr__(self, "center", tuple(float(c) for c in self.center))
        object.__setattr__(self, "size", float(self.size))

    @property
    def half(self) -> float:
        return self.size / 2.0

    @property
    def lower(self) -> NDArray[np.float64]:
        """``(3,)`` minimum corner in metres."""
        return np.asarray(self.center, np.float64) - self.half

    @property
    def upper(self) -> NDArray[np.float64]:
        """``(3,)`` maximum corner in metres."""
        return np.asarray(self.center, np.float64) + self.half

    def contains(self, points: np.ndarray) -> NDArray[np.bool_]:
        """Boolean ``(...)`` mask of the points ``(..., 3)`` inside the cube (boundary included)."""
        points = np.asarray(points)
        inside: NDArray[np.bool_] = np.all((points >= self.lower) & (points <= self.upper), axis=-1)
        return inside

    def normalize(self, points: np.ndarray) -> NDArray[np.float64]:
        """World metres ``(..., 3)`` -> cube coordinates, ``[-1, 1]^3`` inside the cube."""
        return (np.asarray(points, np.float64) - np.asarray(self.center, np.float64)) / self.half

    def denormalize(self, coords: np.ndarray) -> NDArray[np.float64]:
        """Cube coordinates ``(..., 3)`` -> world metres."""
        return np.asarray(coords, np.float64) * self.half + np.asarray(self.center, np.float64)
