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

from pathlib import Path
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


NOT_NUMBERS = frozenset({"string", "image", "video"})
"""Feature dtypes of ``meta/info.json`` whose columns abm does not read as numbers (it reads every other as numbers)."""


def plain_type(typ: pa.DataType) -> pa.DataType:
    """The storage type of an arrow extension type (Hugging Face ``datasets`` registers ``Array2D`` and the like,
    so a process that has imported it, as LeRobot always does, reads 2-D columns as those); the type otherwise."""
    import pyarrow as pa

    while isinstance(typ, pa.ExtensionType):
        typ = typ.storage_type
    return typ


def plain_table(table: pa.Table) -> pa.Table:
    """``table`` with every extension-typed column replaced by its storage (the same values as plain arrow
    lists), so the reader sees the same columns whether or not ``datasets`` was imported in this process."""
    import pyarrow as pa

    for i, field in enumerate(table.schema):
        if isinstance(field.type, pa.ExtensionType):
            column = table.column(i)
            storage = pa.chunked_array([chunk.storage for chunk in column.chunks], type=plain_type(field.type))
            table = table.set_column(i, pa.field(field.name, storage.type, field.nullable), storage)
    return table


def innermost_type(typ: pa.DataType) -> pa.DataType:
    """The element type of a (nested) list column's type; the type itself otherwise (extension types read as
    their storage, :func:`plain_type`)."""
    import pyarrow as pa

    typ = plain_type(typ)
    while pa.types.is_list(typ) or pa.types.is_large_list(typ) or pa.types.is_fixed_size_list(typ):
        typ = plain_type(typ.value_type)
    return typ


def holds_numbers(typ: pa.DataType) -> bool:
    """Whether a column of this arrow type holds numbers (integers, floats or booleans, nested or not)."""
    import pyarrow as pa

    inner = innermost_type(typ)
    return bool(pa.types.is_integer(inner) or pa.types.is_floating(inner) or pa.types.is_boolean(inner))


def non_numeric_column(path: Path, name: str, typ: pa.DataType, declared: object) -> LeRobotFormatError:
    """The error for a frame column that holds something other than numbers although abm reads it as numbers
    (``declared``: its dtype in ``meta/info.json``), naming the file, the column and what it holds."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    inner = innermost_type(typ)
    kind = "text" if pa.types.is_string(inner) or pa.types.is_large_string(inner) else f"{inner} values"
    try:
        values = pq.read_table(path, columns=[name]).column(name).combine_chunks()
        while not pa.types.is_primitive(values.type) and hasattr(values, "flatten"):
            values = values.flatten()
        example = next((v for v in values.to_pylist() if v is not None), None)
        shown = f" (e.g. {str(example)[:40]!r})" if example is not None else ""
    except Exception:  # noqa: BLE001 - the example is a courtesy; the error stands without it
        shown = ""
    return LeRobotFormatError(f"{path}: column {name!r} holds {kind}{shown}, not numbers; meta/info.json declares it "
                              f"{declared!r}: write the column as numbers (or import a dataset whose frames match "
                              "its features)")


def column_array(col: pa.ChunkedArray, shape: list[int], dtype: DTypeLike) -> np.ndarray:
    """A parquet column of ``n`` frames as an ``(n, *shape)`` array (``(n,)`` for ``shape == [1]``); nested
    lists of either kind (fixed-size as abm writes them, variable as Hugging Face ``datasets`` does) work."""
    n = len(col)
    try:
        if shape == [1]:
            return np.asarray(col.to_numpy(zero_copy_only=False), dtype)
        flat = col.combine_chunks()
        for _ in shape:
            flat = flat.flatten()
        values = np.asarray(flat.to_numpy(zero_copy_only=False), dtype)
    except (TypeError, ValueError) as err:  # the import checks the column types first; this is the last guard
        raise LeRobotFormatError(f"a column of {n} frames holds values that are not {np.dtype(dtype).name} ({err})"
                                 ) from None
    if values.size != n * int(np.prod(shape)):
        raise LeRobotFormatError(f"a column of {n} frames holds {values.size} values, not {n} x {shape}")
    return values.reshape(n, *shape)
