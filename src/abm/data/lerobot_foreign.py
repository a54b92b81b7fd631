"""Import of LeRobot v3.0 datasets that abm did not write (``abm data import --format lerobot DS --task NAME``).

An abm episode is a sequence of keyframes, each with the fused point cloud of every camera, so abm needs,
besides the colour images and the instruction (the episode's LeRobot task string):

* per camera ``C`` (``observation.images.C``, video or image): its depth and calibration, under the names abm's
  own exports use (:mod:`abm.data.lerobot_schema`)
  - ``geometry.depth.C``: float ``[H, W]``, metres along the camera's +z axis (0 = no measurement),
  - ``geometry.intrinsics.C``: ``[3, 3]`` pinhole matrix (OpenCV, pixels),
  - ``geometry.extrinsics.C``: ``[4, 4]`` camera-to-world transform (OpenCV camera axes),
  - optionally ``geometry.segmentation.C``: int ``[H, W]`` object ids (-1 = none);
  cameras without them are left out (with a warning); a dataset where no camera has them is refused;
* the gripper per frame: ``observation.state`` whose ``names`` include ``x, y, z, qx, qy, qz, qw`` (TCP
  position, m, and orientation, in the frame of the extrinsics) and ``gripper_open`` (0 = closed ... 1 = open),
  or ``robot.gripper_pose`` (``[4, 4]`` TCP-to-world) and a ``gripper_open`` state entry;
* the ABM-Bench task its episodes show (``--task``; LeRobot datasets name none) and the split (``--split``).

Keyframes are found in the dense frames the way PerAct / RVT find them (:func:`detect_keyframes`): where the
gripper opens or closes, where the TCP comes to rest, and the last frame. Each becomes the target of the
keyframe before it, whose observation is the frame where that segment starts. Episodes are imported as
keyframe-only episodes (no dense trajectory: abm's is in its robot's joints), successful, with no object names
(no oracle grounding; a learned grounder reads the images).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from abm.data.lerobot_schema import (
    GRIPPER_POSE_KEY,
    IMAGE_PREFIX,
    STATE_KEY,
    LeRobotFormatError,
    column_array,
    depth_key,
    extrinsics_key,
    intrinsics_key,
    segmentation_key,
)
from abm.geometry import canonical_gripper_quat, pose_matrix
from abm.geometry.rotations import matrix_to_quat
from abm.types import CameraFrame, Episode, KeyframeAction, Observation

if TYPE_CHECKING:
    import pyarrow as pa

#: Speed (m/s) under which the TCP counts as at rest, for :func:`detect_keyframes`.
REST_SPEED = 0.01
POSE_NAMES = ("x", "y", "z", "qx", "qy", "qz", "qw")
GRIPPER_NAME = "gripper_open"
DOCS = "docs/datasets.md, section 'Importing other LeRobot datasets'"


@dataclass(frozen=True)
class ForeignLayout:
    """What abm reads from a LeRobot dataset it did not write (:func:`foreign_layout`)."""

    cameras: list[str]
    """The cameras with depth and calibration (imported)."""
    skipped: list[str]
    """Cameras without them (left out)."""
    state_names: list[str]
    """The ``names`` of ``observation.state``."""
    pose_from_state: bool
    """The TCP pose comes from ``observation.state`` (else from ``robot.gripper_pose``)."""


def _names(feature: Mapping[str, Any]) -> list[str]:
    """A feature's entry names (LeRobot writes a list, some datasets ``{"motors": [...]}``)."""
    names = feature.get("names")
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    return [str(n) for n in names] if isinstance(names, list) else []


def foreign_layout(ds: Path, features: Mapping[str, Mapping[str, Any]]) -> ForeignLayout:
    """Check that a dataset not written by abm has what an abm episode needs, and say where it is.

    Raises:
        LeRobotFormatError: naming what is missing (depth and calibration per camera, the gripper pose and
            opening) and where the documentation describes it.
    """
    cameras = [k[len(IMAGE_PREFIX):] for k, f in features.items()
               if k.startswith(IMAGE_PREFIX) and f.get("dtype") in ("video", "image")]
    if not cameras:
        raise LeRobotFormatError(f"{ds}: the dataset has no camera (a feature observation.images.<camera> of dtype "
                                 "video or image); abm needs colour images with depth and calibration")
    complete: list[str] = []
    skipped: list[str] = []
    lacking: list[str] = []
    for cam in cameras:
        shape = list(features[IMAGE_PREFIX + cam].get("shape", []))
        wanted = {depth_key(cam): shape[:2], intrinsics_key(cam): [3, 3], extrinsics_key(cam): [4, 4]}
        if segmentation_key(cam) in features:
            wanted[segmentation_key(cam)] = shape[:2]
        missing = [k for k in wanted if k not in features]
        for key, want in wanted.items():
            if key in features and list(features[key].get("shape", [])) != want:
                raise LeRobotFormatError(f"{ds}: feature {key} has shape {features[key].get('shape')}, abm needs "
                                         f"{want} (see {DOCS})")
        (skipped if missing else complete).append(cam)
        lacking += missing
    if not complete:
        cam = cameras[0]
        raise LeRobotFormatError(
            f"{ds} was not written by abm data export, and abm cannot rebuild its point clouds: for every camera C "
            f"abm needs its depth and calibration as the features geometry.depth.C (float [H, W], metres along the "
            f"camera's +z axis), geometry.intrinsics.C ([3, 3] pinhole matrix, pixels) and geometry.extrinsics.C "
            f"([4, 4] camera-to-world, OpenCV camera axes). The dataset has the camera(s) "
            f"{', '.join(IMAGE_PREFIX + c for c in cameras)} but not {', '.join(lacking)} (e.g. {depth_key(cam)}). "
            f"Add these columns (see {DOCS}), or record the demonstrations with abm data generate")
    state_names = _names(features.get(STATE_KEY, {}))
    pose_from_state = GRIPPER_POSE_KEY not in features
    need = [*POSE_NAMES, GRIPPER_NAME] if pose_from_state else [GRIPPER_NAME]
    if STATE_KEY not in features or any(n not in state_names for n in need):
        raise LeRobotFormatError(
            f"{ds}: abm needs the gripper's pose and opening in every frame: observation.state with the names "
            f"{', '.join(POSE_NAMES)} (TCP position in metres and orientation, in the frame of the camera "
            f"extrinsics) and {GRIPPER_NAME} (0 = closed, 1 = open), or the feature {GRIPPER_POSE_KEY} ([4, 4] "
            f"TCP-to-world) and a {GRIPPER_NAME} state entry; "
            + (f"observation.state has the names {state_names}" if STATE_KEY in features
               else "the dataset has no observation.state") + f" (see {DOCS})")
    return ForeignLayout(complete, skipped, state_names, pose_from_state)


def detect_keyframes(position: NDArray[np.float64], gripper_open: NDArray[np.float64], fps: float,
                     rest_speed: float = REST_SPEED) -> NDArray[np.int64]:
    """The frames a demonstration's keyframes reach, found as PerAct and RVT find them: a frame where the
    gripper has just opened or closed (its opening crossed 0.5), a frame where the TCP comes to rest (it moved
    at ``rest_speed`` m/s or more into the frame and moves slower out of it), and the last frame.

    Args:
        position: ``(T, 3)`` TCP positions (m).
        gripper_open: ``(T,)`` gripper opening, 0 = closed, 1 = open.
        fps: the frame rate of the recording.

    Returns:
        The sorted frames (all after frame 0; empty for fewer than two frames).
    """
    n = len(position)
    if n < 2:
        return np.zeros(0, np.int64)
    closed = np.asarray(gripper_open) < 0.5
    changed = np.flatnonzero(closed[1:] != closed[:-1]) + 1
    moving = np.linalg.norm(np.diff(np.asarray(position, np.float64), axis=0), axis=1) * fps >= rest_speed
    arrived = np.flatnonzero(moving[:-1] & ~moving[1:]) + 1
    frames = np.union1d(np.union1d(changed, arrived), [n - 1]).astype(np.int64)
    return frames[frames > 0]


def foreign_episode(layout: ForeignLayout, meta: Mapping[str, Any], instruction: str,
                    cols: Mapping[str, pa.ChunkedArray], rgb: Mapping[str, np.ndarray], fps: float) -> Episode:
    """The keyframe episode of one LeRobot episode (its frame columns and decoded camera images)."""
    where = f"episode {meta.get('lerobot_episode_index')}"
    state = column_array(cols[STATE_KEY], [len(layout.state_names)], np.float64)
    index = {name: i for i, name in enumerate(layout.state_names)}
    opening = np.clip(state[:, index[GRIPPER_NAME]], 0.0, 1.0)
    if layout.pose_from_state:
        quats = state[:, [index[n] for n in POSE_NAMES[3:]]]
        if not np.all(np.linalg.norm(quats, axis=1) > 1e-6):
            raise LeRobotFormatError(f"{where}: observation.state has a zero quaternion (qx, qy, qz, qw)")
        poses = np.stack([pose_matrix(p, q / np.linalg.norm(q))
                          for p, q in zip(state[:, [index[n] for n in POSE_NAMES[:3]]], quats, strict=True)])
    else:
        poses = column_array(cols[GRIPPER_POSE_KEY], [4, 4], np.float64)
    if not np.all(np.isfinite(poses)):
        raise LeRobotFormatError(f"{where}: the gripper pose is not finite in every frame")
    targets = detect_keyframes(poses[:, :3, 3], opening, fps)
    if not len(targets):
        raise LeRobotFormatError(f"{where} has {len(state)} frame(s); abm needs at least two to make a keyframe")
    frames = np.concatenate([[0], targets[:-1]]).astype(np.int64)
    observations = []
    for k, f in enumerate(frames):
        cameras = {}
        for cam in layout.cameras:
            h, w = rgb[cam].shape[1:3]
            seg_key = segmentation_key(cam)
            cameras[cam] = CameraFrame(
                rgb=rgb[cam][f], depth=_row(cols[depth_key(cam)], f, [h, w], np.float32),
                intrinsics=_row(cols[intrinsics_key(cam)], f, [3, 3], np.float64),
                extrinsics=_row(cols[extrinsics_key(cam)], f, [4, 4], np.float64),
                segmentation=_row(cols[seg_key], f, [h, w], np.int32) if seg_key in cols else None)
        observations.append(Observation(cameras=cameras, gripper_open=float(opening[f]), gripper_pose=poses[f],
                                        step=k))
    steps = [(obs, KeyframeAction(poses[t][:3, 3], canonical_gripper_quat(matrix_to_quat(poses[t][:3, :3]), 2),
                                  bool(opening[t] >= 0.5)))
             for obs, t in zip(observations, targets, strict=True)]
    try:
        return Episode(task=str(meta["task"]), variation=0, split=str(meta["split"]), instruction=instruction,
                       object_names={}, target_names=[], steps=steps, success=True, seed=-1,
                       metadata=dict(meta["metadata"]))
    except ValueError as err:
        raise LeRobotFormatError(f"{where}: {err}") from None


def _row(col: pa.ChunkedArray, frame: int, shape: list[int], dtype: type[np.generic]) -> np.ndarray:
    """One frame's value of an array column."""
    value: np.ndarray = column_array(col.slice(frame, 1), shape, dtype)[0]
    return value
