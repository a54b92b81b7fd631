"""SE(3) augmentation applied consistently to a point cloud and a keyframe action.

A random rigid transform — a yaw about the vertical axis through the workspace centre followed by a
translation — moves the whole cloud and the action with it, so the action still points at the
same object point. Defaults follow RVT/PerAct: translation uniform in ±0.125 m per axis, yaw uniform
in ±45 degrees.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from abm.geometry.rotations import canonical_gripper_matrix, matrix_to_quat, quat_to_matrix
from abm.geometry.workspace import Workspace
from abm.types import KeyframeAction


def random_se3(
    rng: np.random.Generator,
    workspace: Workspace,
    max_translation: float = 0.125,
    max_yaw_deg: float = 45.0,
) -> np.ndarray:
    """Sample a ``(4, 4)`` world-frame transform: yaw about the vertical through the cube centre, then shift."""
    yaw = rng.uniform(-max_yaw_deg, max_yaw_deg)
    shift = rng.uniform(-max_translation, max_translation, size=3)
    rot = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
    center = np.asarray(workspace.center)
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = center - rot @ center + shift
    return out


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a ``(4, 4)`` transform to points ``(..., 3)``."""
    points = np.asarray(points)
    moved: np.ndarray = (points @ transform[:3, :3].T + transform[:3, 3]).astype(points.dtype, copy=False)
    return moved


def transform_action(transform: np.ndarray, action: KeyframeAction) -> KeyframeAction:
    """Apply a ``(4, 4)`` world transform to a keyframe (position and orientation).

    The turned orientation is put back into its canonical member (``action.symmetry``), so an
    augmented label follows the same convention as the stored ones: a yaw of 45 degrees can move a
    label across the canonical range's edge, and the equivalent orientation on the other side is used.
    """
    pos = transform[:3, :3] @ action.position + transform[:3, 3]
    rot = canonical_gripper_matrix(transform[:3, :3] @ quat_to_matrix(action.quaternion), action.symmetry)
    return KeyframeAction(pos, matrix_to_quat(rot), action.gripper_open, action.ignore_collision,
                          action.kind, action.symmetry)


def augment_cloud(
    points: np.ndarray,
    action: KeyframeAction,
    workspace: Workspace,
    rng: np.random.Generator,
    max_translation: float = 0.125,
    max_yaw_deg: float = 45.0,
    max_tries: int = 20,
) -> tuple[np.ndarray, KeyframeAction, np.ndarray]:
    """Randomly move a point cloud and its action together.

    A transform is resampled (up to ``max_tries`` times) until the augmented action stays inside the
    workspace; if none does, the identity is used so the sample is never lost.

    Args:
        points: ``(N, 3)`` world points.
        action: the keyframe of this sample.

    Returns:
        ``(points, action, transform)`` after augmentation; ``transform`` is the ``(4, 4)`` applied.
    """
    for _ in range(max_tries):
        transform = random_se3(rng, workspace, max_translation, max_yaw_deg)
        moved = transform_action(transform, action)
        if workspace.contains(moved.position):
            return transform_points(transform, points), moved, transform
    return np.asarray(points), action, np.eye(4)
