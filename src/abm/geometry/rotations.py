"""Rotation helpers: quaternions (x, y, z, w), Euler angles, matrices and RVT-style rotation bins.

Conversions go through :class:`scipy.spatial.transform.Rotation`. Euler angles use scipy's
extrinsic ``"xyz"`` convention (rotate about world x, then world y, then world z).

Rotation discretisation: each Euler angle in degrees is mapped to one of ``num_bins`` bins of width
``360 / num_bins`` (72 bins = 5 degrees). Bin ``i`` is centred at ``-180 + i * width`` (so 0, ±90 and
180 degrees are bin centres and decode exactly; -180 and 180 share bin 0). Decoding a bin and
encoding again is exact, and any angle decodes within half a bin (2.5 degrees for 72 bins).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

EULER_ORDER = "xyz"
DEFAULT_ROTATION_BINS = 72


def normalize_quaternion(quat: np.ndarray) -> NDArray[np.float64]:
    """Unit quaternion ``(..., 4)`` with non-negative ``w`` (the two signs are the same rotation)."""
    quat = np.asarray(quat, np.float64)
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("cannot normalise a zero quaternion")
    quat = quat / norm
    return np.where(quat[..., 3:4] < 0, -quat, quat)


def quat_to_matrix(quat: np.ndarray) -> NDArray[np.float64]:
    """``(..., 4)`` quaternions (x, y, z, w) -> ``(..., 3, 3)`` rotation matrices."""
    quat = np.asarray(quat, np.float64)
    matrix: NDArray[np.float64] = Rotation.from_quat(quat.reshape(-1, 4)).as_matrix()
    return matrix.reshape(*quat.shape[:-1], 3, 3)


def matrix_to_quat(matrix: np.ndarray) -> NDArray[np.float64]:
    """``(..., 3, 3)`` rotation matrices -> ``(..., 4)`` unit quaternions (x, y, z, w), ``w >= 0``."""
    matrix = np.asarray(matrix, np.float64)
    quat: NDArray[np.float64] = Rotation.from_matrix(matrix.reshape(-1, 3, 3)).as_quat()
    return normalize_quaternion(quat).reshape(*matrix.shape[:-2], 4)


def quat_to_euler(quat: np.ndarray, degrees: bool = True) -> NDArray[np.float64]:
    """``(..., 4)`` quaternions -> ``(..., 3)`` extrinsic xyz Euler angles."""
    quat = np.asarray(quat, np.float64)
    euler: NDArray[np.float64] = Rotation.from_quat(quat.reshape(-1, 4)).as_euler(EULER_ORDER, degrees=degrees)
    return euler.reshape(*quat.shape[:-1], 3)


def euler_to_quat(euler: np.ndarray, degrees: bool = True) -> NDArray[np.float64]:
    """``(..., 3)`` extrinsic xyz Euler angles -> ``(..., 4)`` unit quaternions (x, y, z, w)."""
    euler = np.asarray(euler, np.float64)
    quat: NDArray[np.float64] = Rotation.from_euler(EULER_ORDER, euler.reshape(-1, 3), degrees=degrees).as_quat()
    return normalize_quaternion(quat).reshape(*euler.shape[:-1], 4)


def pose_matrix(position: np.ndarray, quat: np.ndarray) -> NDArray[np.float64]:
    """Position ``(3,)`` (m) and quaternion ``(4,)`` -> ``(4, 4)`` homogeneous transform."""
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(quat)
    out[:3, 3] = position
    return out


def quat_angle_deg(q1: np.ndarray, q2: np.ndarray) -> NDArray[np.float64]:
    """Geodesic angle in degrees between two (batches of) quaternions."""
    r = Rotation.from_quat(np.atleast_2d(q1)).inv() * Rotation.from_quat(np.atleast_2d(q2))
    magnitude: NDArray[np.float64] = r.magnitude()
    return np.degrees(magnitude).reshape(np.broadcast_shapes(np.shape(q1)[:-1], np.shape(q2)[:-1]))


def euler_to_bins(euler_deg: np.ndarray, num_bins: int = DEFAULT_ROTATION_BINS) -> NDArray[np.int64]:
    """Euler angles in degrees ``(..., 3)`` -> integer bins ``(..., 3)`` in ``[0, num_bins)``."""
    width = 360.0 / num_bins
    shifted = np.asarray(euler_deg, np.float64) + 180.0
    return np.mod(np.round(shifted / width).astype(np.int64), num_bins)


def bins_to_euler(bins: np.ndarray, num_bins: int = DEFAULT_ROTATION_BINS) -> NDArray[np.float64]:
    """Integer bins ``(..., 3)`` -> Euler angles in degrees at the bin centres."""
    bins = np.asarray(bins)
    if np.any(bins < 0) or np.any(bins >= num_bins):
        raise ValueError(f"rotation bins must lie in [0, {num_bins}), got {bins.tolist()}")
    width = 360.0 / num_bins
    return -180.0 + bins.astype(np.float64) * width


def quat_to_bins(quat: np.ndarray, num_bins: int = DEFAULT_ROTATION_BINS) -> NDArray[np.int64]:
    """Quaternion(s) ``(..., 4)`` -> Euler bins ``(..., 3)``."""
    return euler_to_bins(quat_to_euler(quat, degrees=True), num_bins)


def bins_to_quat(bins: np.ndarray, num_bins: int = DEFAULT_ROTATION_BINS) -> NDArray[np.float64]:
    """Euler bins ``(..., 3)`` -> quaternion(s) ``(..., 4)`` at the bin centres."""
    return euler_to_quat(bins_to_euler(bins, num_bins), degrees=True)


# --- gripper symmetry and canonical labels ----------------------------------------------------------
#: World yaw (degrees) of the finger axis (the TCP's y axis) that canonical gripper orientations lie
#: closest to. -45 degrees keeps the Panda's last wrist joint near mid-range for top-down grasps over
#: the table, so every canonical top-down orientation is reachable without a wrist wind-up.
GRIPPER_REFERENCE_YAW_DEG = -45.0
#: Symmetry order of a parallel gripper alone: turning it by 180 degrees about its axis is the same grasp.
GRIPPER_SYMMETRY = 2
#: Symmetry order meaning "any turn about the gripper axis" (a round object grasped from above).
ROUND_SYMMETRY = 0
_ROUND_SAMPLES = 360


def _reference_axis(z_axis: np.ndarray, reference_yaw_deg: float) -> NDArray[np.float64]:
    """Unit reference direction for the finger axis, projected onto the plane normal to ``z_axis``."""
    yaw = np.radians(reference_yaw_deg)
    for ref in (np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.array([0.0, 0.0, 1.0])):
        proj = ref - z_axis * float(ref @ z_axis)
        norm = float(np.linalg.norm(proj))
        if norm > 1e-6:
            return proj / norm
    raise AssertionError("unreachable: two orthogonal references cannot both be parallel to z")


def _turn_z(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def canonical_gripper_matrix(rotation: np.ndarray, symmetry: int = GRIPPER_SYMMETRY,
                             reference_yaw_deg: float = GRIPPER_REFERENCE_YAW_DEG) -> NDArray[np.float64]:
    """The canonical member of a gripper orientation's equivalence class.

    Orientations ``R @ Rz(360° k / symmetry)`` (turns about the gripper's own z axis) are the same grasp:
    ``symmetry`` 2 for the parallel gripper alone, 4 for a square object grasped from above, 1 for none,
    and :data:`ROUND_SYMMETRY` (0) for any turn. The canonical member is the one whose finger axis
    (TCP y) is closest to the reference direction (world yaw ``reference_yaw_deg``, projected onto the
    plane normal to the gripper axis). For a top-down grasp this puts the finger yaw within
    ``±180° / symmetry`` of the reference (a round object gets exactly the reference yaw).

    Args:
        rotation: ``(3, 3)`` TCP-to-world rotation.
        symmetry: number of equivalent turns (see above).
        reference_yaw_deg: world yaw (degrees) of the reference finger direction.

    Returns:
        ``(3, 3)`` rotation with the same gripper axis.
    """
    rot = np.asarray(rotation, np.float64)
    if symmetry < 0:
        raise ValueError(f"symmetry must be >= 0 (0 = any turn), got {symmetry}")
    z = rot[:, 2]
    ref = _reference_axis(z, reference_yaw_deg)
    if symmetry == ROUND_SYMMETRY:
        # Turn about z so the finger axis equals the reference: angle from the current y to ref.
        angle = np.arctan2(float(np.cross(rot[:, 1], ref) @ z), float(rot[:, 1] @ ref))
        return rot @ _turn_z(angle)
    candidates = [rot @ _turn_z(2 * np.pi * k / symmetry) for k in range(max(symmetry, 1))]
    # Ties (exactly 180° / symmetry from the reference, a measure-zero set) go to the smallest turn of
    # the given member, so the result is deterministic for an input but can differ between members.
    scores = [round(float(c[:, 1] @ ref), 9) for c in candidates]
    return candidates[int(np.argmax(scores))]


def canonical_gripper_quat(quat: np.ndarray, symmetry: int = GRIPPER_SYMMETRY) -> NDArray[np.float64]:
    """Quaternion ``(4,)`` (x, y, z, w) version of :func:`canonical_gripper_matrix`."""
    return matrix_to_quat(canonical_gripper_matrix(quat_to_matrix(quat), symmetry))


def symmetric_angle_deg(q1: np.ndarray, q2: np.ndarray, symmetry: int = GRIPPER_SYMMETRY) -> float:
    """Smallest rotation angle (degrees) between ``q1`` and any orientation equivalent to ``q2``.

    Equivalent orientations are turns about ``q2``'s gripper axis by ``360° / symmetry`` (see
    :func:`canonical_gripper_matrix`; 0 = any turn, sampled every degree).
    """
    r1 = quat_to_matrix(q1)
    r2 = quat_to_matrix(q2)
    if symmetry == ROUND_SYMMETRY:
        angles = np.linspace(0.0, 2 * np.pi, _ROUND_SAMPLES, endpoint=False)
    else:
        angles = 2 * np.pi * np.arange(max(symmetry, 1)) / max(symmetry, 1)
    others = np.stack([r2 @ _turn_z(a) for a in angles])
    rel = Rotation.from_matrix(np.einsum("ji,njk->nik", r1, others))
    return float(np.degrees(rel.magnitude().min()))
