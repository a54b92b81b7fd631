"""Names and constants of abm's LeRobot v3.0 datasets, shared by the export, the import of abm's own datasets
and the import of other LeRobot datasets (:mod:`abm.data.lerobot`, :mod:`abm.data.lerobot_foreign`).

Feature names follow how LeRobot routes a dataset's features to a policy
(``lerobot.datasets.utils.dataset_to_policy_features``): a ``video``/``image`` feature is a camera, the key
``observation.environment_state`` is the environment state, **every other key starting with**
``observation`` **is robot state** and every key starting with ``action`` is an action; anything else is
loaded with the frames but given to no policy. So only what a policy should read is under
``observation.*`` / ``action``:

* ``observation.images.<camera>``: the camera images;
* ``observation.state``: the proprioceptive state (TCP pose and gripper opening);
* ``action``: what the policy learns to output;

and abm's extra columns are in namespaces LeRobot's policies skip: ``geometry.*`` (depth, segmentation,
camera calibration), ``robot.*`` (exact TCP pose, joint positions, the end-effector form of the action),
``keyframe.*`` (keyframe labels) and ``abm.*`` (bookkeeping).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import DTypeLike

from abm.errors import DataError

if TYPE_CHECKING:  # pyarrow is imported where datasets are written or read
    import pyarrow as pa

CODEBASE_VERSION = "v3.0"
#: ``abm.format`` in ``meta/info.json``: 2 = the namespaces above, keyframe exports with their images in the
#: parquet; 1 (no ``abm.format``) = the first exports, with everything under ``observation.*`` (still read).
ABM_FORMAT = 2
#: Top-level ``meta/info.json`` key saying how frames were sampled: :data:`FIXED_RATE` (``fps`` is the frame
#: rate) or :data:`KEYFRAMES` (one frame per keyframe; ``fps`` is only LeRobot's index step, not a rate).
FRAME_SAMPLING = "frame_sampling"
FIXED_RATE = "fixed_rate"
KEYFRAMES = "keyframes"
#: LeRobot's ``fps`` of a keyframe export: a time offset of ``k`` (seconds) selects the ``k``-th next keyframe.
KEYFRAME_INDEX_FPS = 1

CHUNKS_SIZE = 1000  # files per chunk folder (LeRobot's default)
DATA_FILE_MB = 100.0  # LeRobot's default data_files_size_in_mb
VIDEO_FILE_MB = 200.0  # LeRobot's default video_files_size_in_mb
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DATA_FILE = DATA_PATH.format(chunk_index=0, file_index=0)
EPISODES_FILE = EPISODES_PATH.format(chunk_index=0, file_index=0)
TASKS_FILE = "meta/tasks.parquet"
EXPORT_MARKER = ".export-incomplete"  # in a dataset folder while abm data export writes it

STATE_NAMES = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open"]
JOINT_NAMES = [f"joint{i}" for i in range(1, 8)] + ["finger_left", "finger_right"]
JOINT_ACTION_NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]
EE_ACTION_NAMES = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper"]
STAT_NAMES = ("min", "max", "mean", "std", "count")

STATE_KEY = "observation.state"
ACTION_KEY = "action"
GRIPPER_POSE_KEY = "robot.gripper_pose"
JOINTS_KEY = "robot.joint_positions"
EE_ACTION_KEY = "robot.ee_action"
STEP_KEY = "abm.observation_step"
IMAGE_PREFIX = "observation.images."


class LeRobotFormatError(DataError):
    """A dataset folder that is not a LeRobot v3 dataset abm can import (the message says why)."""


def image_key(camera: str) -> str:
    """The feature of a camera's colour images."""
    return f"{IMAGE_PREFIX}{camera}"


def depth_key(camera: str) -> str:
    """The feature of a camera's depth maps (float32 ``[H, W]``, metres along the camera's +z, 0 = none)."""
    return f"geometry.depth.{camera}"


def segmentation_key(camera: str) -> str:
    """The feature of a camera's segmentation (int32 ``[H, W]`` object ids, -1 = none)."""
    return f"geometry.segmentation.{camera}"


def intrinsics_key(camera: str) -> str:
    """The feature of a camera's pinhole matrix (float64 ``[3, 3]``, OpenCV, pixels)."""
    return f"geometry.intrinsics.{camera}"


def extrinsics_key(camera: str) -> str:
    """The feature of a camera's pose (float64 ``[4, 4]`` camera-to-world, OpenCV camera axes)."""
    return f"geometry.extrinsics.{camera}"


def format1_key(key: str) -> str:
    """The current name of a feature of a format-1 export (everything was under ``observation.*``)."""
    for old, new in (("observation.depth.", "geometry.depth."),
                     ("observation.segmentation.", "geometry.segmentation."),
                     ("observation.intrinsics.", "geometry.intrinsics."),
                     ("observation.extrinsics.", "geometry.extrinsics.")):
        if key.startswith(old):
            return new + key[len(old):]
    return {"observation.gripper_pose": GRIPPER_POSE_KEY, "observation.joint_positions": JOINTS_KEY,
            "observation.step": STEP_KEY, "action.ee": EE_ACTION_KEY}.get(key, key)


def column_array(col: pa.ChunkedArray, shape: list[int], dtype: DTypeLike) -> np.ndarray:
    """A parquet column of ``n`` frames as an ``(n, *shape)`` array (``(n,)`` for ``shape == [1]``); nested
    lists of either kind (fixed-size as abm writes them, variable as Hugging Face ``datasets`` does) work."""
    n = len(col)
    if shape == [1]:
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype)
    flat = col.combine_chunks()
    for _ in shape:
        flat = flat.flatten()
    values = np.asarray(flat.to_numpy(zero_copy_only=False), dtype)
    if values.size != n * int(np.prod(shape)):
        raise LeRobotFormatError(f"a column of {n} frames holds {values.size} values, not {n} x {shape}")
    return values.reshape(n, *shape)
