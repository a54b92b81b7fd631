"""A built-in synthetic RGB-D scene: coloured blocks on a table, seen by four analytic pinhole cameras.

It needs nothing but numpy (no simulator), renders exactly (ray casting against planes and boxes),
and comes with ground-truth segmentation, so it serves as a sample scene for the commands and as
known geometry for tests. Camera names and placement mimic the simulator's: ``front``,
``left_shoulder``, ``right_shoulder`` and ``wrist``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from abm.types import CameraFrame, Observation

TABLE_HALF_EXTENT = (0.45, 0.6)  # table top: x in [0.05, 0.95], y in [-0.6, 0.6], z = 0
SYNTHETIC_TABLE_CENTER_X = 0.5
TABLE_COLOR = np.array([0.62, 0.55, 0.45])
BLOCK_COLORS: dict[str, tuple[float, float, float]] = {
    "red": (0.85, 0.15, 0.12),
    "green": (0.15, 0.7, 0.2),
    "blue": (0.15, 0.3, 0.85),
    "yellow": (0.92, 0.85, 0.15),
    "purple": (0.55, 0.2, 0.7),
    "orange": (0.95, 0.55, 0.1),
}
CAMERA_POSES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # name: (eye, look-at point), world metres
    "front": ((1.35, 0.0, 0.6), (0.45, 0.0, 0.0)),
    "left_shoulder": ((0.1, 0.55, 0.65), (0.55, -0.05, 0.0)),
    "right_shoulder": ((0.1, -0.55, 0.65), (0.55, 0.05, 0.0)),
    "wrist": ((0.5, 0.0, 0.55), (0.5, 0.0, 0.0)),
}


@dataclass(frozen=True)
class Box:
    """An axis-aligned box: centre and half-extents in metres, RGB colour in ``[0, 1]``."""

    name: str
    center: tuple[float, float, float]
    half: tuple[float, float, float]
    color: tuple[float, float, float]


def look_at(eye: np.ndarray, target: np.ndarray) -> NDArray[np.float64]:
    """``(4, 4)`` camera-to-world transform (OpenCV axes) of a camera at ``eye`` looking at ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    forward = target - eye
    forward /= np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    out = np.eye(4)
    out[:3, :3] = np.stack([right, down, forward], axis=1)
    out[:3, 3] = eye
    return out


def pinhole_intrinsics(resolution: int, fovy_deg: float) -> NDArray[np.float64]:
    """``(3, 3)`` intrinsics of a square image with vertical field of view ``fovy_deg`` (OpenCV pixel centres)."""
    f = (resolution / 2.0) / np.tan(np.radians(fovy_deg) / 2.0)
    c = (resolution - 1) / 2.0
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def sample_blocks(rng: np.random.Generator, count: int = 4, size: float = 0.05) -> list[Box]:
    """``count`` cubes of edge ``size`` with distinct colours at non-overlapping table positions."""
    names = rng.choice(list(BLOCK_COLORS), size=count, replace=False)
    boxes: list[Box] = []
    while len(boxes) < count:
        xy = rng.uniform([0.3, -0.3], [0.7, 0.3])
        if all(np.hypot(xy[0] - b.center[0], xy[1] - b.center[1]) > 2.5 * size for b in boxes):
            name = str(names[len(boxes)])
            boxes.append(Box(f"{name} block", (xy[0], xy[1], size / 2), (size / 2,) * 3, BLOCK_COLORS[name]))
    return boxes


def raycast(
    boxes: list[Box], intrinsics: np.ndarray, extrinsics: np.ndarray, resolution: int
) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.int32]]:
    """Ray-cast the table and boxes.

    Returns:
        ``rgb`` ``(H, W, 3)`` uint8, ``depth`` ``(H, W)`` float32 metres along the camera axis
        (0 where a ray hits nothing) and ``segmentation`` ``(H, W)`` int32 (box index, -1 otherwise).
    """
    rows, cols = np.mgrid[0:resolution, 0:resolution].astype(np.float64)
    d_cam = np.stack([(cols - intrinsics[0, 2]) / intrinsics[0, 0],
                      (rows - intrinsics[1, 2]) / intrinsics[1, 1], np.ones_like(rows)], axis=-1)
    d = d_cam @ extrinsics[:3, :3].T  # world direction per pixel; its camera-z component is 1
    o = extrinsics[:3, 3]
    t_best = np.full(rows.shape, np.inf)
    seg = np.full(rows.shape, -1, np.int32)
    normal = np.zeros(rows.shape + (3,))
    color = np.zeros(rows.shape + (3,))

    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[..., 2]
        hit = t > 0
        px, py = o[0] + t * d[..., 0], o[1] + t * d[..., 1]
        hit &= (np.abs(px - SYNTHETIC_TABLE_CENTER_X) <= TABLE_HALF_EXTENT[0]) & (np.abs(py) <= TABLE_HALF_EXTENT[1])
        t_best = np.where(hit, t, t_best)
        checker = ((np.floor(px / 0.1) + np.floor(py / 0.1)) % 2)[..., None]
        color = np.where(hit[..., None], TABLE_COLOR * (0.9 + 0.1 * checker), color)
        normal[hit] = (0.0, 0.0, 1.0)

        for idx, box in enumerate(boxes):
            lo = np.asarray(box.center) - box.half
            hi = np.asarray(box.center) + box.half
            t1, t2 = (lo - o) / d, (hi - o) / d
            t_near = np.minimum(t1, t2).max(-1)
            t_far = np.maximum(t1, t2).min(-1)
            hit = (t_near <= t_far) & (t_near > 0) & (t_near < t_best)
            axis = np.minimum(t1, t2).argmax(-1)
            n = np.zeros(rows.shape + (3,))
            np.put_along_axis(n, axis[..., None], -np.sign(np.take_along_axis(d, axis[..., None], -1)), -1)
            t_best = np.where(hit, t_near, t_best)
            seg = np.where(hit, idx, seg)
            normal = np.where(hit[..., None], n, normal)
            color = np.where(hit[..., None], np.asarray(box.color), color)

    light = np.array([0.3, 0.2, 0.93])
    shade = 0.55 + 0.45 * np.clip(normal @ (light / np.linalg.norm(light)), 0.0, 1.0)
    rgb = np.clip(color * shade[..., None] * 255.0, 0, 255).astype(np.uint8)
    depth = np.where(np.isfinite(t_best), t_best, 0.0).astype(np.float32)
    return rgb, depth, seg


def synthetic_scene(
    seed: int = 0, resolution: int = 128, num_blocks: int = 4, fovy_deg: float = 60.0
) -> tuple[Observation, dict[int, str]]:
    """Build the sample scene.

    Args:
        seed: block colours and positions.
        resolution: camera image side in pixels.
        num_blocks: number of coloured cubes (at most 6).
        fovy_deg: vertical field of view of every camera.

    Returns:
        the :class:`Observation` of the four cameras (gripper open, above the table) and the
        segmentation id -> object name map (e.g. ``{0: "red block", ...}``).
    """
    if not 1 <= num_blocks <= len(BLOCK_COLORS):
        raise ValueError(f"num_blocks must be in [1, {len(BLOCK_COLORS)}], got {num_blocks}")
    boxes = sample_blocks(np.random.default_rng(seed), num_blocks)
    intrinsics = pinhole_intrinsics(resolution, fovy_deg)
    cameras = {}
    for name, (eye, target) in CAMERA_POSES.items():
        extrinsics = look_at(np.asarray(eye), np.asarray(target))
        rgb, depth, seg = raycast(boxes, intrinsics, extrinsics, resolution)
        cameras[name] = CameraFrame(rgb, depth, intrinsics.copy(), extrinsics, seg)
    gripper = np.eye(4)
    gripper[:3, :3] = np.diag([1.0, -1.0, -1.0])  # pointing down
    gripper[:3, 3] = (0.5, 0.0, 0.55)
    obs = Observation(cameras=cameras, gripper_open=1.0, gripper_pose=gripper, step=0)
    return obs, {i: b.name for i, b in enumerate(boxes)}
