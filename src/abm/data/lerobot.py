"""abm episodes <-> LeRobot datasets (``abm data export --format lerobot`` / ``abm data import``).

Writes the LeRobot **v3.0** layout (``codebase_version`` "v3.0", the layout of lerobot 0.4)::

    DS/meta/info.json                                 features (dtype, shape, names), fps, counts, paths,
                                                      frame_sampling, abm (format, frames, cameras, sha256)
    DS/meta/stats.json                                min / max / mean / std / count / q01 ... q99 per feature
    DS/meta/tasks.parquet                             task string (the instruction) -> task_index
    DS/meta/episodes/chunk-000/file-000.parquet       one row per episode: length, frame range, data and video
                                                      file and range, stats/<feature>/<stat>, and
                                                      ``abm/episode`` (JSON: task, split, seed, objects, ...)
    DS/data/chunk-CCC/file-FFF.parquet                one row per frame, one row group per episode
    DS/videos/observation.images.<camera>/chunk-CCC/file-FFF.mp4   episodes of a camera back to back

Features are named so LeRobot's policies read what they should (:mod:`abm.data.lerobot_schema`): the cameras
``observation.images.*``, the proprioceptive state ``observation.state``, the action ``action``; depth,
segmentation and calibration are ``geometry.*``, the exact TCP pose, joint positions and end-effector action
``robot.*``, keyframe labels ``keyframe.*``, none of which a LeRobot policy takes as state.

Dense exports (episodes recorded with ``abm data generate --dense``; the default when every episode has its
trajectory) have one frame per control tick at the recording rate (``fps``; ``timestamp = frame_index / fps``)
and H.264 videos (yuv420p, lossy). Keyframe exports have one frame per keyframe: ``frame_sampling:
"keyframes"`` in ``info.json``, ``keyframe.is_keyframe`` true on every frame, the camera images as PNG in the
parquet (LeRobot's ``image`` dtype: no video, whose frames are found by time, has to pretend a frame rate),
``timestamp`` the time of the keyframe in the recording when the episode was recorded ``--dense`` and NaN
otherwise, and ``fps`` 1, which LeRobot needs and uses as an index step only (a ``delta_timestamps`` offset of
``k`` is the ``k``-th next keyframe).

Files are split like LeRobot's: a data file is closed before an episode would take it past
``data_files_size_in_mb`` (judged by the file's bytes per frame so far), a video file before an episode's
encoded video would take it past ``video_files_size_in_mb`` (each episode is encoded on its own, then
appended); an episode is never split across files.

Integrity and containment: the export checks every episode's checksums before it writes anything, records
the sha256 of every parquet and video file in ``meta/info.json`` (``abm.sha256``), and on failure removes only
what it created. The import checks those sha256, refuses episodes marked failed, unknown tasks and file names
that leave ``--out``, replaces existing episodes only with ``overwrite``, and marks ``--out`` with
``.import-incomplete`` until the last episode is written. Datasets not written by abm are imported through
:mod:`abm.data.lerobot_foreign` (they need depth and calibration).
"""

from __future__ import annotations

import io
import json
import logging
import os
import shlex
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from abm.configuration import SPLITS
from abm.data.episode_store import (
    IMPORT_MARKER,
    EpisodeFormatError,
    EpisodeStore,
    check_episodes,
    load_episode,
    load_metadata,
    outdated_task_version,
    save_episode,
)
from abm.data.lerobot_foreign import ForeignLayout, foreign_episode, foreign_layout
from abm.data.lerobot_schema import (
    ABM_FORMAT,
    ACTION_KEY,
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILE,
    DATA_FILE_MB,
    DATA_PATH,
    EE_ACTION_KEY,
    EE_ACTION_NAMES,
    EPISODES_FILE,
    EXPORT_MARKER,
    FIXED_RATE,
    FRAME_SAMPLING,
    GRIPPER_POSE_KEY,
    JOINT_ACTION_NAMES,
    JOINT_NAMES,
    JOINTS_KEY,
    KEYFRAME_INDEX_FPS,
    KEYFRAMES,
    NOT_NUMBERS,
    STATE_KEY,
    STATE_NAMES,
    STEP_KEY,
    TASKS_FILE,
    VIDEO_FILE_MB,
    VIDEO_PATH,
    LeRobotFormatError,
    column_array,
    depth_key,
    extrinsics_key,
    format1_key,
    holds_numbers,
    image_key,
    intrinsics_key,
    non_numeric_column,
    plain_table,
    segmentation_key,
)
from abm.data.lerobot_stats import aggregate_stats, feature_stats
from abm.errors import ConfigError, DataError, OutputError
from abm.files import is_inside, sha256_file, write_text_atomic
from abm.geometry.rotations import matrix_to_quat
from abm.sim.tasks import TASKS
from abm.types import CameraFrame, Episode, KeyframeAction, Observation, Trajectory

if TYPE_CHECKING:  # pyarrow is imported where datasets are written or read
    import pyarrow as pa

__all__ = ["DATA_FILE", "EPISODES_FILE", "EXPORT_MARKER", "ExportReport", "LeRobotFormatError", "export_lerobot",
           "import_lerobot"]

_EXPORT_ENTRIES = ("data", "meta", "videos")  # what an export creates in its --out folder (besides the marker)
_MB = 1024 * 1024  # LeRobot's megabyte (get_file_size_in_mb)


@dataclass
class ExportReport:
    """What :func:`export_lerobot` wrote."""

    episodes: int
    frames: int
    fps: float
    dense: bool
    bytes: int
    files: list[str] = field(default_factory=list)
    """The dataset's parquet and video files (relative paths)."""

    def summary(self, out: str | os.PathLike[str]) -> str:
        """One line on what was written to ``out`` (``abm data export`` prints it)."""
        kind = f"dense frames at {self.fps:g} fps" if self.dense else "keyframes (one frame per keyframe)"
        data = sum(name.startswith("data/") for name in self.files)
        videos = len(self.files) - data
        files = f"{data} data file{'s' * (data != 1)}" + (
            f", {videos} video file{'s' * (videos != 1)}" if videos else "")
        return (f"{self.episodes} episodes, {self.frames} {kind} -> {out} (LeRobot v3.0, {files}, "
                f"{self.bytes / 1e6:.1f} MB)")


# --- features and columns ------------------------------------------------------------------------------


def _features(cameras: list[str], size: tuple[int, int], dense: bool, segmentation: bool, fps: float,
              crf: int) -> dict[str, dict[str, Any]]:
    h, w = size
    feats: dict[str, dict[str, Any]] = {}
    for cam in cameras:
        if dense:
            feats[image_key(cam)] = {
                "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channels"],
                "info": {"video.height": h, "video.width": w, "video.codec": "h264", "video.pix_fmt": "yuv420p",
                         "video.is_depth_map": False, "video.fps": fps, "video.channels": 3, "video.crf": crf,
                         "has_audio": False}}
        else:
            feats[image_key(cam)] = {"dtype": "image", "shape": [h, w, 3], "names": ["height", "width", "channels"]}
    feats[STATE_KEY] = {"dtype": "float32", "shape": [8], "names": STATE_NAMES,
                        "info": {"meaning": "TCP position (m) and orientation in the robot base (world) frame, "
                                            "gripper opening in [0, 1]"}}
    if dense:
        feats[ACTION_KEY] = {"dtype": "float32", "shape": [8], "names": JOINT_ACTION_NAMES,
                             "info": {"meaning": "arm joint servo targets (rad) and gripper command (1 = open) of "
                                                 "the next control tick"}}
    else:
        feats[ACTION_KEY] = {"dtype": "float32", "shape": [8], "names": EE_ACTION_NAMES,
                             "info": {"meaning": "the next keyframe: TCP target and gripper open"}}
    for cam in cameras:
        feats[depth_key(cam)] = {"dtype": "float32", "shape": [h, w], "names": ["height", "width"],
                                 "info": {"unit": "m, along the camera +z axis; 0 = no measurement"}}
        if segmentation:
            feats[segmentation_key(cam)] = {"dtype": "int32", "shape": [h, w], "names": ["height", "width"],
                                            "info": {"values": "object id (abm/episode object_names), -1 = none"}}
        feats[intrinsics_key(cam)] = {"dtype": "float64", "shape": [3, 3], "names": None,
                                      "info": {"convention": "OpenCV pinhole, pixels"}}
        feats[extrinsics_key(cam)] = {"dtype": "float64", "shape": [4, 4], "names": None,
                                      "info": {"convention": "camera-to-world, OpenCV camera axes"}}
    feats[GRIPPER_POSE_KEY] = {"dtype": "float64", "shape": [4, 4], "names": None,
                               "info": {"meaning": "the exact TCP-to-world transform"}}
    if dense:
        feats[JOINTS_KEY] = {"dtype": "float64", "shape": [9], "names": JOINT_NAMES}
        feats[EE_ACTION_KEY] = {"dtype": "float32", "shape": [8], "names": EE_ACTION_NAMES,
                                "info": {"meaning": "the action as a TCP target: the next control tick's TCP pose "
                                                    "and the gripper command"}}
    feats["keyframe.is_keyframe"] = {"dtype": "bool", "shape": [1], "names": None}
    feats["keyframe.index"] = {"dtype": "int64", "shape": [1], "names": None,
                               "info": {"meaning": "the keyframe this frame moves to (its observation if "
                                                   "is_keyframe)"}}
    feats["keyframe.position"] = {"dtype": "float64", "shape": [3], "names": ["x", "y", "z"]}
    feats["keyframe.quaternion"] = {"dtype": "float64", "shape": [4], "names": ["qx", "qy", "qz", "qw"]}
    feats["keyframe.gripper_open"] = {"dtype": "bool", "shape": [1], "names": None}
    feats["keyframe.ignore_collision"] = {"dtype": "bool", "shape": [1], "names": None}
    feats["keyframe.kind"] = {"dtype": "string", "shape": [1], "names": None}
    feats["keyframe.symmetry"] = {"dtype": "int64", "shape": [1], "names": None}
    feats[STEP_KEY] = {"dtype": "int64", "shape": [1], "names": None}
    feats["timestamp"] = {"dtype": "float32", "shape": [1], "names": None,
                          "info": {"meaning": "frame_index / fps" if dense else
                                   "s since the episode start at which the keyframe was observed, for episodes "
                                   "recorded with --dense; NaN (not recorded) for keyframe-only episodes"}}
    for key in ("frame_index", "episode_index", "index", "task_index"):
        feats[key] = {"dtype": "int64", "shape": [1], "names": None}
    return feats


def _image_type() -> pa.DataType:
    """Arrow storage of Hugging Face ``datasets.Image`` (LeRobot's ``image`` dtype)."""
    import pyarrow as pa

    return pa.struct([("bytes", pa.binary()), ("path", pa.string())])


def _arrow_type(feature: dict[str, Any]) -> pa.DataType:
    import pyarrow as pa

    if feature["dtype"] == "image":
        return _image_type()
    base = {"float32": pa.float32(), "float64": pa.float64(), "int32": pa.int32(), "int64": pa.int64(),
            "bool": pa.bool_(), "string": pa.string()}[feature["dtype"]]
    shape = feature["shape"]
    if shape == [1]:
        return base
    for n in reversed(shape):
        base = pa.list_(base, n)
    return base


def _column(feature: dict[str, Any], values: Any) -> pa.Array:
    import pyarrow as pa

    typ = _arrow_type(feature)
    if feature["dtype"] == "image":
        return pa.array([{"bytes": b, "path": None} for b in values], type=typ)
    if feature["shape"] == [1]:
        return pa.array(values, type=typ)
    arr = np.ascontiguousarray(values)
    out = pa.array(arr.reshape(-1), type=typ.value_type if len(feature["shape"]) == 1 else None)
    for n in reversed(feature["shape"]):
        out = pa.FixedSizeListArray.from_arrays(out, n)
    return out


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG")
    return buffer.getvalue()


# --- file writers ----------------------------------------------------------------------------------------


def _next_file(index: tuple[int, int]) -> tuple[int, int]:
    """LeRobot's ``update_chunk_file_indices``: the next file, in the next chunk after ``CHUNKS_SIZE`` files."""
    chunk, file = index
    return (chunk + 1, 0) if file + 1 >= CHUNKS_SIZE else (chunk, file + 1)


class _DataFiles:
    """The frame parquet files: a new file is started before an episode would take the current one past the
    size limit, judged by the file's bytes per frame so far (as LeRobot does)."""

    def __init__(self, out: Path, schema: pa.Schema, limit_mb: float) -> None:
        self.out, self.schema, self.limit = out, schema, limit_mb * _MB
        self.index = (0, 0)
        self.sink: pa.OSFile | None = None
        self.writer: Any = None
        self.rows = 0
        self.paths: list[str] = []

    def write(self, table: pa.Table) -> tuple[int, int]:
        """Append one episode's rows (one row group); returns the ``(chunk, file)`` they went to."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        if self.sink is not None and self.rows:
            size = self.sink.tell()
            if size + size / self.rows * table.num_rows > self.limit:
                self.close()
                self.index = _next_file(self.index)
        if self.sink is None:
            name = DATA_PATH.format(chunk_index=self.index[0], file_index=self.index[1])
            (self.out / name).parent.mkdir(parents=True, exist_ok=True)
            self.sink = pa.OSFile(str(self.out / name), "wb")
            self.writer = pq.ParquetWriter(self.sink, self.schema, compression="zstd")
            self.rows = 0
            self.paths.append(name)
        self.writer.write_table(table, row_group_size=max(table.num_rows, 1))
        self.rows += table.num_rows
        return self.index

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if self.sink is not None:
            self.sink.close()
        self.sink, self.writer = None, None


def _encode_video(frames: np.ndarray, rate: Fraction, crf: int) -> bytes:
    """One episode's frames as an H.264 (yuv420p) mp4 in memory, frame ``i`` at ``i / rate`` s."""
    import av

    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        stream.time_base = 1 / rate
        stream.options = {"crf": str(crf), "g": "10"}
        for i, img in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            frame.pts = i
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return buffer.getvalue()


class _VideoFiles:
    """One camera's mp4 files: each episode is encoded on its own, then its packets are appended to the
    current file (shifted in time) unless they would take it past the size limit, which starts a new file."""

    def __init__(self, out: Path, key: str, fps: float, crf: int, limit_mb: float) -> None:
        self.out, self.key, self.fps, self.crf, self.limit = out, key, fps, crf, limit_mb * _MB
        self.rate = Fraction(fps).limit_denominator(1000)
        self.index = (0, 0)
        self.container: Any = None
        self.stream: Any = None
        self.frames = 0
        self.bytes = 0
        self.paths: list[str] = []

    def write(self, frames: np.ndarray) -> tuple[int, int, float, float]:
        """Append one episode; returns its ``(chunk, file, from_timestamp, to_timestamp)``."""
        import av

        encoded = _encode_video(frames, self.rate, self.crf)
        if self.container is not None and self.frames and self.bytes + len(encoded) > self.limit:
            self.close()
            self.index = _next_file(self.index)
        if self.container is None:
            name = VIDEO_PATH.format(video_key=self.key, chunk_index=self.index[0], file_index=self.index[1])
            (self.out / name).parent.mkdir(parents=True, exist_ok=True)
            self.container = av.open(str(self.out / name), "w")
            self.stream, self.frames, self.bytes = None, 0, 0
            self.paths.append(name)
        start = self.frames
        with av.open(io.BytesIO(encoded), "r") as source:
            template = source.streams.video[0]
            if self.stream is None:
                self.stream = self.container.add_stream_from_template(template)
            for packet in source.demux(template):
                if packet.dts is None:  # the demuxer's end-of-stream packet
                    continue
                assert packet.time_base is not None and packet.pts is not None
                shift = round(Fraction(start) / self.rate / packet.time_base)
                packet.pts += shift
                packet.dts += shift
                packet.stream = self.stream
                self.container.mux(packet)
        self.frames += len(frames)
        self.bytes += len(encoded)
        return self.index[0], self.index[1], float(start / self.rate), float(self.frames / self.rate)

    def close(self) -> None:
        if self.container is not None:
            self.container.close()
        self.container = None


# --- export ----------------------------------------------------------------------------------------------


def _frames_of(episode: Episode, dense: bool) -> tuple[list[Observation], np.ndarray, np.ndarray]:
    """Observations of the exported frames, the keyframe each frame moves to, and the is-keyframe flags."""
    if not dense:
        k = np.arange(len(episode.steps))
        return [o for o, _ in episode.steps], k, np.ones(len(k), bool)
    traj = episode.trajectory
    assert traj is not None
    n = len(traj)
    flags = np.zeros(n, bool)
    flags[traj.keyframe_frames] = True
    segment = np.searchsorted(traj.keyframe_frames, np.arange(n), side="right") - 1
    return traj.observations, np.clip(segment, 0, max(len(episode.steps) - 1, 0)), flags


def _source_name(path: Path, root: Path) -> str:
    try:
        return path.relative_to(root).as_posix()
    except ValueError:
        return path.name


def export_lerobot(data: str | os.PathLike[str], out: str | os.PathLike[str], frames: str = "auto", crf: int = 18,
                   robot_type: str = "franka_panda", progress: bool = True, data_file_mb: float = DATA_FILE_MB,
                   video_file_mb: float = VIDEO_FILE_MB) -> ExportReport:
    """Write every episode under ``data`` as one LeRobot v3 dataset in ``out`` (a new or empty folder).

    Args:
        frames: ``"dense"`` (the ``--dense`` trajectories at their recording rate), ``"keyframes"``, or
            ``"auto"`` (dense when every episode has a trajectory).
        crf: H.264 quality of the camera videos (0 = best, 51 = worst; 18 is visually lossless).
        data_file_mb, video_file_mb: size limits of the parquet and mp4 files (MiB, LeRobot's
            ``data_files_size_in_mb`` / ``video_files_size_in_mb``).
    """
    import av  # noqa: F401 - a missing video library fails here, before anything is written
    import pyarrow as pa

    data, out = Path(data), Path(out)
    if not data.is_dir():
        raise ConfigError(f"--data {data} is not a folder of abm episodes")
    _check_export_target(out)
    if frames not in ("auto", "dense", "keyframes"):
        raise ConfigError(f"--frames must be auto, dense or keyframes, got {frames!r}")
    if not 0 <= crf <= 51:
        raise ConfigError(f"--crf must be between 0 and 51, got {crf}")
    if not (data_file_mb > 0 and video_file_mb > 0):
        raise ConfigError(f"file size limits must be positive, got {data_file_mb} and {video_file_mb} MB")
    store = EpisodeStore(data)
    if not len(store):
        raise ConfigError(f"no abm episodes (*.h5) under {data}")
    store.check_consistent(range(len(store)))
    bad = check_episodes([info.path for info in store.episodes], data)  # before a byte of the export is written
    if bad:
        shown = "; ".join(reason for _, reason in bad[:3]) + (f"; and {len(bad) - 3} more" if len(bad) > 3 else "")
        raise EpisodeFormatError(f"{len(bad)} episode file(s) in {data} fail verification, so nothing was exported: "
                                 f"{shown}. Run abm data generate again with the same arguments (it re-creates "
                                 "them), then export again")
    first = load_episode(store.episodes[0].path)
    cameras = list(first.steps[0][0].cameras)
    cam0 = first.steps[0][0].cameras[cameras[0]]
    size = (cam0.height, cam0.width)
    segmentation = all(c.segmentation is not None for c in first.steps[0][0].cameras.values())
    dense_all = all("dense_fps" in load_metadata(i.path) for i in store.episodes)
    if frames == "dense" and not dense_all:
        missing = next(i.path for i in store.episodes if "dense_fps" not in load_metadata(i.path))
        raise ConfigError(f"--frames dense: {missing} has no dense trajectory (generate with --dense)")
    dense = frames == "dense" or (frames == "auto" and dense_all)
    if frames == "auto" and not dense_all and any("dense_fps" in load_metadata(i.path) for i in store.episodes):
        missing = next(i.path for i in store.episodes if "dense_fps" not in load_metadata(i.path))
        logging.getLogger("abm").warning("%s: some episodes have no dense trajectory (e.g. %s), so all are exported "
                                         "at their keyframes; export the --dense ones on their own for a dense "
                                         "dataset", data, missing)
    if dense and (size[0] % 2 or size[1] % 2):
        raise ConfigError(f"the episodes' images are {size[0]}x{size[1]}; H.264 video (yuv420p) needs even sizes "
                          "(export --frames keyframes keeps the images as PNG)")
    fps = float(first.trajectory.fps) if dense and first.trajectory is not None else float(KEYFRAME_INDEX_FPS)
    features = _features(cameras, size, dense, segmentation, fps, crf)
    schema = pa.schema([(k, _arrow_type(f)) for k, f in features.items() if f["dtype"] != "video"])

    created = _first_missing(out)  # everything from here down is this export's own, removed if it fails
    try:
        out.mkdir(parents=True, exist_ok=True)
        return _write_export(store, first, out, cameras, segmentation, dense, fps, features, schema, crf,
                             robot_type, progress, (data_file_mb, video_file_mb))
    except BaseException:
        _remove_export(out, created)
        raise


def _check_export_target(out: Path) -> None:
    """``--out`` must be a new or an empty folder (an export never replaces or mixes with other files)."""
    if out.is_symlink() and not out.exists():
        raise OutputError(f"--out {out} is a symbolic link to a missing folder; give a new folder")
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} exists and is not an empty folder (it is a file); give a new folder")
    if out.is_dir() and any(out.iterdir()):
        if (out / EXPORT_MARKER).exists():
            raise OutputError(f"--out {out} exists and is not an empty folder: it holds an export that did not "
                              f"finish ({out / EXPORT_MARKER}); delete that folder yourself and export again, or "
                              "give a new folder")
        raise OutputError(f"--out {out} exists and is not an empty folder; give a new folder")


def _first_missing(path: Path) -> Path | None:
    """The outermost of ``path`` and its parents that does not exist yet (``None`` if ``path`` exists)."""
    missing = None
    for p in (path, *path.parents):
        if p.exists() or p.is_symlink():
            break
        missing = p
    return missing


def _remove_export(out: Path, created: Path | None) -> None:
    """Remove what a failed export wrote: the folders it created, or (in an ``--out`` folder that existed,
    empty) the entries it made there. Nothing else is ever deleted."""
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    for name in (*_EXPORT_ENTRIES, EXPORT_MARKER):
        path = out / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        elif path.exists() or path.is_symlink():
            path.unlink(missing_ok=True)


def _timestamps(episode: Episode, dense: bool, n: int, fps: float) -> NDArray[np.float32]:
    """Frame times (s): ``i / fps`` for dense frames; for keyframes the time each was observed in the dense
    recording, or NaN when the episode was recorded at keyframes only (no time was kept)."""
    if dense:
        return (np.arange(n) / fps).astype(np.float32)
    traj = episode.trajectory
    if traj is None:
        return np.full(n, np.nan, np.float32)
    return (traj.keyframe_frames / traj.fps).astype(np.float32)


def _episode_columns(episode: Episode, dense: bool, cameras: list[str], segmentation: bool,
                     fps: float) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The frame columns of one episode (by feature name, without the images) and each camera's images."""
    observations, target, flags = _frames_of(episode, dense)
    n = len(observations)
    actions = [a for _, a in episode.steps]
    cols: dict[str, Any] = {}
    rgb: dict[str, np.ndarray] = {}
    for cam in cameras:
        cf = [o.cameras[cam] for o in observations]
        rgb[cam] = np.stack([c.rgb for c in cf])
        cols[depth_key(cam)] = np.stack([c.depth for c in cf]).astype(np.float32)
        if segmentation:  # every frame has one when the first has (a missing one fails in np.stack)
            cols[segmentation_key(cam)] = np.stack(cast("list[np.ndarray]", [c.segmentation for c in cf]))
        cols[intrinsics_key(cam)] = np.stack([c.intrinsics for c in cf])
        cols[extrinsics_key(cam)] = np.stack([c.extrinsics for c in cf])
    poses = np.stack([o.gripper_pose for o in observations])
    cols[STATE_KEY] = np.concatenate([poses[:, :3, 3], matrix_to_quat(poses[:, :3, :3]),
                                      np.array([[o.gripper_open] for o in observations])], axis=1).astype(np.float32)
    cols[GRIPPER_POSE_KEY] = poses
    cols[STEP_KEY] = np.array([o.step for o in observations], np.int64)
    kf_pos = np.array([actions[k].position for k in target]).reshape(n, 3)
    kf_quat = np.array([actions[k].quaternion for k in target]).reshape(n, 4)
    kf_open = np.array([actions[k].gripper_open for k in target], bool)
    if dense:
        traj = episode.trajectory
        assert traj is not None  # checked by the caller
        cols[JOINTS_KEY] = traj.joint_positions
        cols[ACTION_KEY] = traj.joint_actions.astype(np.float32)
        cols[EE_ACTION_KEY] = traj.ee_actions.astype(np.float32)
    else:
        cols[ACTION_KEY] = np.concatenate([kf_pos, kf_quat, kf_open[:, None]], axis=1).astype(np.float32)
    cols["keyframe.is_keyframe"] = flags
    cols["keyframe.index"] = target.astype(np.int64)
    cols["keyframe.position"] = kf_pos
    cols["keyframe.quaternion"] = kf_quat
    cols["keyframe.gripper_open"] = kf_open
    cols["keyframe.ignore_collision"] = np.array([actions[k].ignore_collision for k in target], bool)
    cols["keyframe.kind"] = [actions[k].kind for k in target]
    cols["keyframe.symmetry"] = np.array([actions[k].symmetry for k in target], np.int64)
    cols["frame_index"] = np.arange(n, dtype=np.int64)
    cols["timestamp"] = _timestamps(episode, dense, n, fps)
    return cols, rgb


def _write_export(store: EpisodeStore, first: Episode, out: Path, cameras: list[str], segmentation: bool,
                  dense: bool, fps: float, features: dict[str, dict[str, Any]], schema: pa.Schema, crf: int,
                  robot_type: str, progress: bool, limits: tuple[float, float]) -> ExportReport:
    """Write the dataset into the (empty) folder ``out``; see :func:`export_lerobot`."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    marker = out / EXPORT_MARKER
    marker.write_text("abm data export is writing this dataset\n")
    data_files = _DataFiles(out, schema, limits[0])
    videos = {cam: _VideoFiles(out, image_key(cam), fps, crf, limits[1]) for cam in cameras} if dense else {}
    tasks: dict[str, int] = {}
    rows: list[dict[str, Any]] = []
    episode_stats: list[dict[str, dict[str, np.ndarray]]] = []
    total = 0
    try:
        for ep_index, info in enumerate(tqdm(store.episodes, desc="export", unit="ep", disable=not progress)):
            episode = load_episode(info.path) if ep_index else first
            if dense:
                if episode.trajectory is None:
                    raise DataError(f"{info.path} has no dense trajectory (generate with --dense)")
                if abs(episode.trajectory.fps - fps) > 1e-9:
                    raise DataError(f"{info.path} was recorded at {episode.trajectory.fps} fps, the first episode "
                                    f"at {fps}")
            cols, rgb = _episode_columns(episode, dense, cameras, segmentation, fps)
            n = len(cols["frame_index"])
            cols["episode_index"] = np.full(n, ep_index, np.int64)
            cols["index"] = np.arange(total, total + n, dtype=np.int64)
            cols["task_index"] = np.full(n, tasks.setdefault(episode.instruction, len(tasks)), np.int64)
            if not dense:
                for cam in cameras:
                    cols[image_key(cam)] = [_png(img) for img in rgb[cam]]
            chunk, file = data_files.write(pa.table({k: _column(features[k], cols[k]) for k in schema.names},
                                                    schema=schema))
            row: dict[str, Any] = {"episode_index": ep_index, "tasks": [episode.instruction], "length": n,
                                   "data/chunk_index": chunk, "data/file_index": file, "dataset_from_index": total,
                                   "dataset_to_index": total + n}
            for cam, writer in videos.items():
                v_chunk, v_file, start, end = writer.write(rgb[cam])
                key = image_key(cam)
                row |= {f"videos/{key}/chunk_index": v_chunk, f"videos/{key}/file_index": v_file,
                        f"videos/{key}/from_timestamp": start, f"videos/{key}/to_timestamp": end}
            row |= {"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0}
            stats = {}
            for key, feature in features.items():
                values = rgb[key.removeprefix("observation.images.")] if feature["dtype"] in ("video", "image") \
                    else cols[key]
                if (st := feature_stats(feature, values)) is not None:
                    stats[key] = st
                    row |= {f"stats/{key}/{name}": value.tolist() for name, value in st.items()}
            meta = {"task": episode.task, "split": episode.split, "variation": episode.variation,
                    "object_names": {str(k): v for k, v in episode.object_names.items()},
                    "target_names": list(episode.target_names), "success": bool(episode.success),
                    "seed": int(episode.seed), "metadata": episode.metadata, "cameras": cameras,
                    "source": _source_name(info.path, store.root), "frames": "dense" if dense else "keyframes"}
            row["abm/episode"] = json.dumps(meta, default=_json_default)
            rows.append(row)
            episode_stats.append(stats)
            total += n
    finally:
        data_files.close()
        for writer in videos.values():
            writer.close()

    (out / EPISODES_FILE).parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), out / EPISODES_FILE)
    _write_tasks(out / TASKS_FILE, tasks)
    keys = [k for k in features if any(k in s for s in episode_stats)]
    (out / "meta" / "stats.json").write_text(json.dumps(
        {k: aggregate_stats([s[k] for s in episode_stats if k in s]) for k in keys}, indent=1))
    files = [*data_files.paths, *(p for writer in videos.values() for p in writer.paths)]
    info_json = {
        "codebase_version": CODEBASE_VERSION, "robot_type": robot_type, "total_episodes": len(rows),
        "total_frames": total, "total_tasks": len(tasks), "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": limits[0], "video_files_size_in_mb": limits[1],
        "fps": int(fps) if fps.is_integer() else fps, "splits": {"train": f"0:{len(rows)}"},
        "data_path": DATA_PATH, "video_path": VIDEO_PATH if dense else None, "features": features,
        FRAME_SAMPLING: FIXED_RATE if dense else KEYFRAMES,
        "abm": {"format": ABM_FORMAT, "frames": "dense" if dense else "keyframes", "cameras": cameras,
                "written_by": "abm data export --format lerobot",
                "sha256": {name: sha256_file(out / name) for name in [*files, EPISODES_FILE, TASKS_FILE]},
                "note": ("dense: one frame per control tick at fps, RGB as H.264 mp4" if dense else
                         "keyframes: one frame per keyframe, fps is an index step and not a frame rate, RGB as "
                         "PNG in the parquet") + "; depth, segmentation and calibration are geometry.* columns"}}
    (out / "meta" / "info.json").write_text(json.dumps(info_json, indent=2))
    marker.unlink()
    size_bytes = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return ExportReport(len(rows), total, fps, dense, size_bytes, files)


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def _write_tasks(path: Path, tasks: dict[str, int]) -> None:
    """``meta/tasks.parquet``: the task strings as the (pandas) index, ``task_index`` as the column."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = list(tasks)
    table = pa.table({"task_index": pa.array([tasks[t] for t in names], pa.int64()),
                      "task": pa.array(names, pa.string())})
    pandas_meta = {"index_columns": ["task"], "column_indexes": [],
                   "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                                "numpy_type": "int64", "metadata": None},
                               {"name": "task", "field_name": "task", "pandas_type": "unicode",
                                "numpy_type": "object", "metadata": None}],
                   "creator": {"library": "pyarrow", "version": pa.__version__}, "pandas_version": "2.2.0"}
    pq.write_table(table.replace_schema_metadata({"pandas": json.dumps(pandas_meta)}), path)


# --- import: reading ---------------------------------------------------------------------------------------


def _read_json(path: Path, what: str) -> dict[str, Any]:
    if not path.is_file():
        raise LeRobotFormatError(f"{path.parent.parent}: not a LeRobot dataset ({what} {path} is missing)")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise LeRobotFormatError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise LeRobotFormatError(f"{path}: not a JSON object")
    return data


def _read_parquet(path: Path, skip_prefix: str | None = None) -> pa.Table:
    import pyarrow.parquet as pq

    if not path.is_file():
        raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
    try:
        columns = None
        if skip_prefix is not None:
            columns = [c for c in pq.read_schema(path).names if not c.startswith(skip_prefix)]
        table = pq.read_table(path, columns=columns)
    except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
        raise LeRobotFormatError(f"{path}: not a readable parquet file ({err})") from None
    return plain_table(table)


class _VideoFrames:
    """The frames of one mp4, read in order (constant memory); frame ``i`` is the one shown at ``i / fps``."""

    def __init__(self, path: Path, fps: float) -> None:
        import av

        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        self.path, self.fps = path, fps
        try:
            self._container = av.open(str(path))
            self._frames = self._container.decode(video=0)
        except av.error.FFmpegError as err:
            raise LeRobotFormatError(f"{path}: not a readable video ({err})") from None

    def take(self, lo: int, hi: int) -> np.ndarray:
        """Frames ``lo`` to ``hi - 1`` (after those of the previous call)."""
        import av

        out: list[np.ndarray] = []
        try:
            for frame in self._frames:
                assert frame.pts is not None and frame.time_base is not None  # set on every decoded frame
                i = int(round(float(frame.pts * frame.time_base) * self.fps))
                if i < lo:
                    continue
                if i != lo + len(out):
                    break
                out.append(frame.to_ndarray(format="rgb24"))
                if len(out) == hi - lo:
                    break
        except av.error.FFmpegError as err:
            raise LeRobotFormatError(f"{self.path}: not a readable video ({err})") from None
        if len(out) != hi - lo:
            raise LeRobotFormatError(f"{self.path}: frames {lo + len(out)} to {hi - 1} are missing from the video")
        return np.stack(out)

    def close(self) -> None:
        self._container.close()


class _Rows:
    """Rows of one frame parquet read row group by row group, in order; row ``start`` is the file's first."""

    def __init__(self, path: Path, start: int) -> None:
        import pyarrow.parquet as pq

        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        try:
            self.file = pq.ParquetFile(path)
        except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
            raise LeRobotFormatError(f"{path}: not a readable parquet file ({err})") from None
        self.path, self.group, self.start = path, 0, start
        self.buffer: pa.Table | None = None
        self.column_names = self.file.schema_arrow.names

    def take(self, lo: int, hi: int) -> pa.Table:
        """Rows ``lo`` to ``hi - 1`` (dataset indices, after those of the previous call)."""
        import pyarrow as pa

        if lo < self.start:
            raise LeRobotFormatError(f"{self.path}: rows {lo} to {hi - 1} are not where the episode table says")
        while self.buffer is None or self.start + self.buffer.num_rows < hi:
            if self.group >= self.file.num_row_groups:
                raise LeRobotFormatError(f"{self.path}: rows {lo} to {hi - 1} are missing")
            part = plain_table(self.file.read_row_group(self.group))
            self.group += 1
            self.buffer = part if self.buffer is None else pa.concat_tables([self.buffer, part])
        rows = self.buffer.slice(lo - self.start, hi - lo)
        self.buffer, self.start = self.buffer.slice(hi - self.start), hi
        return rows


def _episode_files(ds: Path) -> list[Path]:
    """The dataset's episode tables (``meta/episodes/chunk-*/file-*.parquet``), in order."""
    files = sorted((ds / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise LeRobotFormatError(f"{ds / EPISODES_FILE} is missing (the dataset is incomplete)")
    return files


def _episode_rows(files: list[Path]) -> list[dict[str, Any]]:
    """Every episode's row (without the stats columns), sorted by its first frame."""
    rows = [r for f in files for r in _read_parquet(f, skip_prefix="stats/").to_pylist()]
    return sorted(rows, key=lambda r: int(r.get("dataset_from_index") or 0))


def _int(row: dict[str, Any], key: str, where: str) -> int:
    try:
        return int(row[key])
    except (KeyError, TypeError, ValueError):
        raise LeRobotFormatError(f"{where}: column {key!r} is missing or not a number") from None


@dataclass
class _Layout:
    """Where an imported dataset's frames are and what its columns are called."""

    ds: Path
    features: dict[str, dict[str, Any]]
    cameras: list[str]
    fps: float
    data_path: str
    video_path: str
    rename: dict[str, str]
    """Dataset column -> the name used here (format-1 exports)."""


class _FrameReader:
    """Reads the episodes' frame rows and camera images across the dataset's files, episode by episode."""

    def __init__(self, layout: _Layout, rows: list[dict[str, Any]]) -> None:
        self.layout = layout
        self.first_row: dict[tuple[int, int], int] = {}
        for row in rows:
            where = f"episode {row.get('episode_index')}"
            key = (_int(row, "data/chunk_index", where), _int(row, "data/file_index", where))
            self.first_row[key] = min(self.first_row.get(key, 1 << 62), _int(row, "dataset_from_index", where))
        self.rows: tuple[tuple[int, int], _Rows] | None = None
        self.videos: dict[str, tuple[tuple[int, int], _VideoFrames]] = {}

    def data_file(self, chunk: int, file: int) -> Path:
        return self.layout.ds / self.layout.data_path.format(chunk_index=chunk, file_index=file)

    def check_columns(self, wanted: Iterable[str]) -> None:
        """Every frame file has the columns ``wanted`` (dataset names), holding numbers where abm reads numbers
        (every feature whose dtype is not in :data:`NOT_NUMBERS`)."""
        import pyarrow.parquet as pq

        for chunk, file in self.first_row:
            path = self.data_file(chunk, file)
            try:
                schema = pq.read_schema(path)
            except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
                raise LeRobotFormatError(f"{path}: not a readable parquet file ({err})") from None
            missing = [k for k in wanted if k not in schema.names]
            if missing:
                raise LeRobotFormatError(f"{path}: columns {missing} listed in meta/info.json are missing")
            for name in wanted:
                declared = self.layout.features.get(name, {}).get("dtype")
                typ = schema.field(name).type
                if declared not in NOT_NUMBERS and not holds_numbers(typ):
                    raise non_numeric_column(path, name, typ, declared)

    def read(self, row: dict[str, Any]) -> tuple[dict[str, pa.ChunkedArray], dict[str, np.ndarray]]:
        """One episode's columns (by the names used here) and camera images ``(n, H, W, 3)``."""
        lay = self.layout
        where = f"episode {row.get('episode_index')}"
        key = (_int(row, "data/chunk_index", where), _int(row, "data/file_index", where))
        lo, hi = _int(row, "dataset_from_index", where), _int(row, "dataset_to_index", where)
        if hi <= lo:
            raise LeRobotFormatError(f"{where} has no frames (dataset_from_index {lo}, dataset_to_index {hi})")
        if self.rows is None or self.rows[0] != key:
            self.rows = key, _Rows(self.data_file(*key), self.first_row[key])
        table = self.rows[1].take(lo, hi)
        if "episode_index" in table.column_names:
            found = set(table.column("episode_index").to_pylist())
            if found != {row.get("episode_index")}:
                raise LeRobotFormatError(f"{self.rows[1].path}: the rows of {where} hold episodes {sorted(found)}")
        cols = {lay.rename.get(k, k): table.column(k) for k in table.column_names}
        rgb = {}
        for cam in lay.cameras:
            vkey = image_key(cam)
            if lay.features[vkey]["dtype"] == "image":
                rgb[cam] = np.stack([_decode_image(v, where) for v in cols[vkey].to_pylist()])
                continue
            file = (_int(row, f"videos/{vkey}/chunk_index", where), _int(row, f"videos/{vkey}/file_index", where))
            if cam not in self.videos or self.videos[cam][0] != file:
                if cam in self.videos:
                    self.videos[cam][1].close()
                path = lay.ds / lay.video_path.format(video_key=vkey, chunk_index=file[0], file_index=file[1])
                self.videos[cam] = file, _VideoFrames(path, lay.fps)
            start = int(round(float(row[f"videos/{vkey}/from_timestamp"]) * lay.fps))
            rgb[cam] = self.videos[cam][1].take(start, start + hi - lo)
        return cols, rgb

    def close(self) -> None:
        for _, video in self.videos.values():
            video.close()


def _decode_image(value: Any, where: str) -> np.ndarray:
    """An ``image`` cell (``{"bytes": PNG/JPEG, "path": ...}``) as ``(H, W, 3)`` uint8."""
    from PIL import Image

    data = value.get("bytes") if isinstance(value, dict) else None
    if not data:
        raise LeRobotFormatError(f"{where}: an image cell holds no image bytes (only images stored in the parquet "
                                 "are read)")
    try:
        with Image.open(io.BytesIO(data)) as img:
            return np.asarray(img.convert("RGB"), np.uint8)
    except OSError as err:
        raise LeRobotFormatError(f"{where}: an image cannot be decoded ({err})") from None


# --- import ----------------------------------------------------------------------------------------------


def import_lerobot(dataset: str | os.PathLike[str], out: str | os.PathLike[str], progress: bool = True,
                   overwrite: bool = False, task: str | None = None, split: str | None = None) -> list[Path]:
    """Read a LeRobot v3 dataset into abm episode files under ``out`` (``OUT/<task>/<split>/episode_<N>.h5``, as
    ``abm data generate`` lays them out). Returns the files. Frames and videos are read episode by episode, so
    memory does not grow with the dataset.

    A dataset written by :func:`export_lerobot` (either format) comes back as it was exported. Any other
    LeRobot v3 dataset needs depth and calibration per camera and the gripper pose and opening per frame
    (:mod:`abm.data.lerobot_foreign`), and ``task`` (and ``split``, default ``"seen"``), which it cannot name.

    Nothing is written before the whole dataset has been checked: the files against the sha256 an abm export
    recorded, every episode's task (a trainable ABM-Bench task), split and outcome (only successful
    demonstrations), and every episode's file name, which must stay inside ``out``. While episodes are written
    ``OUT/.import-incomplete`` marks the folder as partial (:func:`abm.data.episode_store.check_complete`);
    it is removed when the last episode is written, so an import that fails or is stopped stays marked.

    Args:
        overwrite: replace episode files that ``out`` already holds (without it such an import is refused).
        task, split: the ABM-Bench task and split of a dataset not written by abm.

    Raises:
        LeRobotFormatError: the dataset is not one abm can import, or fails a check above.
        ValueError: ``out`` already holds some of the episodes (or an unfinished import) and not ``overwrite``.
    """
    ds, out = Path(dataset), Path(out)
    if not ds.is_dir():
        raise ConfigError(f"LeRobot dataset folder not found: {ds}")
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} is a file; give a folder")
    info = _read_json(ds / "meta" / "info.json", "meta/info.json")
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise LeRobotFormatError(f"{ds}: LeRobot dataset version {version!r}; abm reads {CODEBASE_VERSION!r} "
                                 "(convert older datasets with lerobot's v2.1 -> v3.0 converter)")
    if (ds / EXPORT_MARKER).exists():
        raise LeRobotFormatError(f"{ds}: the export did not finish (remove the folder and export again)")
    features = info.get("features")
    if not isinstance(features, dict) or not all(isinstance(f, dict) for f in features.values()):
        raise LeRobotFormatError(f"{ds}: meta/info.json has no features")
    try:
        fps = float(info["fps"])
        if not fps > 0:
            raise ValueError(f"fps {fps}")
    except (KeyError, TypeError, ValueError) as err:
        raise LeRobotFormatError(f"{ds}: meta/info.json has no valid fps ({err!r})") from None
    abm_info = info.get("abm")
    foreign: ForeignLayout | None = None
    dense = False
    if abm_info is None:
        foreign = foreign_layout(ds, features)
        task, split = _foreign_task(ds, task, split)
        if foreign.skipped:
            logging.getLogger("abm").warning("%s: cameras without depth and calibration are left out: %s", ds,
                                             ", ".join(foreign.skipped))
        layout = _Layout(ds, features, foreign.cameras, fps, str(info.get("data_path") or DATA_PATH),
                         str(info.get("video_path") or VIDEO_PATH), {})
        recorded = None
    else:
        if task is not None or split is not None:
            raise LeRobotFormatError(f"{ds} was written by abm data export, whose episodes name their task and split; "
                                     "--task and --split are for LeRobot datasets written by other tools")
        layout, dense = _abm_layout(ds, info, features, abm_info, fps)
        recorded = _verify_dataset_files(ds, abm_info)
    files = _episode_files(ds)
    rows = _episode_rows(files)
    if recorded is not None:
        _check_recorded(ds, layout, rows, files, recorded)
    if foreign is not None:
        plan = [_plan_foreign(row, ds, out, str(task), str(split)) for row in rows]
    else:
        plan = [_plan_episode(row, ds, out) for row in rows]
    _check_targets(plan, out, overwrite)
    reader = _FrameReader(layout, rows)
    inverse = {new: old for old, new in layout.rename.items()}
    wanted = [inverse.get(k, k) for k in _needed_columns(layout, foreign)]
    reader.check_columns(wanted)
    try:
        out.mkdir(parents=True, exist_ok=True)
        marker = out / IMPORT_MARKER
        redo = f"abm data import --format lerobot {shlex.quote(str(ds))} --out {shlex.quote(str(out))} --overwrite"
        if foreign is not None:
            redo += f" --task {shlex.quote(str(task))} --split {shlex.quote(str(split))}"
        write_text_atomic(marker, f"{redo}\nabm data import is writing this folder; until it finishes, the folder "
                                  "holds only part of the dataset\n")
        written = _import_episodes(plan, reader, layout, foreign, dense, progress)
        marker.unlink()
        return written
    finally:
        reader.close()


def _foreign_task(ds: Path, task: str | None, split: str | None) -> tuple[str, str]:
    """The task and split the episodes of a dataset not written by abm are imported as."""
    trainable = sorted(name for name, cls in TASKS.items() if not cls.evaluation_only)
    if task is None:
        raise LeRobotFormatError(f"{ds} was not written by abm data export (meta/info.json has no abm section), so "
                                 "it does not say which ABM-Bench task its episodes show: pass --task NAME (one of "
                                 f"{', '.join(trainable)}) and, if not seen, --split")
    if task not in trainable:
        raise LeRobotFormatError(f"--task {task!r} is not an ABM-Bench task demonstrations exist for (known: "
                                 f"{', '.join(trainable)})")
    split = "seen" if split is None else split
    if split not in SPLITS:
        raise LeRobotFormatError(f"--split {split!r} is not one of {', '.join(SPLITS)}")
    return task, split


def _abm_layout(ds: Path, info: dict[str, Any], features: dict[str, dict[str, Any]], abm_info: Any,
                fps: float) -> tuple[_Layout, bool]:
    """The layout of a dataset written by abm data export, and whether its frames are dense."""
    if not isinstance(abm_info, dict):
        raise LeRobotFormatError(f"{ds}: meta/info.json's abm section is not a mapping")
    fmt = abm_info.get("format", 1)
    if fmt not in (1, ABM_FORMAT):
        raise LeRobotFormatError(f"{ds}: written by a newer abm (export format {fmt!r}; this abm reads formats 1 "
                                 f"to {ABM_FORMAT}): update abm to import it")
    try:
        cameras = [str(c) for c in abm_info["cameras"]]
        dense = abm_info["frames"] == "dense"
        for cam in cameras:
            feature = features[image_key(cam)]
            if len(feature["shape"]) != 3 or feature["dtype"] not in ("video", "image"):
                raise ValueError(f"camera feature {image_key(cam)} must be a video or image of shape [H, W, 3]")
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise LeRobotFormatError(f"{ds}: meta/info.json is incomplete ({err!r})") from None
    rename = {k: format1_key(k) for k in features if format1_key(k) != k} if fmt == 1 else {}
    return _Layout(ds, features, cameras, fps, str(info.get("data_path") or DATA_PATH),
                   str(info.get("video_path") or VIDEO_PATH), rename), dense


def _needed_columns(layout: _Layout, foreign: ForeignLayout | None) -> list[str]:
    """The frame columns an import reads (names used here)."""
    if foreign is None:
        return [layout.rename.get(k, k) for k, f in layout.features.items() if f.get("dtype") != "video"]
    keys = [STATE_KEY] + ([] if foreign.pose_from_state else [GRIPPER_POSE_KEY])
    for cam in foreign.cameras:
        keys += [depth_key(cam), intrinsics_key(cam), extrinsics_key(cam)]
        keys += [segmentation_key(cam)] if segmentation_key(cam) in layout.features else []
        keys += [image_key(cam)] if layout.features[image_key(cam)]["dtype"] == "image" else []
    return keys


def _safe_name(ds: Path, name: str) -> bool:
    relative = PurePosixPath(name)
    return not relative.is_absolute() and ".." not in relative.parts and is_inside(ds / relative, ds)


def _verify_dataset_files(ds: Path, abm_info: dict[str, Any]) -> set[str] | None:
    """Compare the dataset's files with the sha256 the export recorded; the names checked (``None`` for
    datasets written before abm recorded checksums, read as they are, with a warning)."""
    recorded = abm_info.get("sha256")
    if recorded is None:
        logging.getLogger("abm").warning("%s: written by an abm export that recorded no checksums; its files "
                                         "cannot be verified", ds)
        return None
    if not isinstance(recorded, dict):
        raise LeRobotFormatError(f"{ds}: meta/info.json abm.sha256 is not a mapping of file names to checksums")
    for name, digest in recorded.items():
        if not _safe_name(ds, str(name)):
            raise LeRobotFormatError(f"{ds}: meta/info.json abm.sha256 names {name!r}, which is not inside the "
                                     "dataset; the dataset was not written by abm data export, or was edited")
        path = ds / str(name)
        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        if sha256_file(path) != digest:
            raise LeRobotFormatError(f"{path} does not match the checksum the export recorded; the dataset is "
                                     "corrupt: export it again from the abm episodes")
    return {str(name) for name in recorded}


def _check_recorded(ds: Path, layout: _Layout, rows: list[dict[str, Any]], files: list[Path],
                    recorded: set[str]) -> None:
    """Every file an import reads is among those whose checksum the export recorded."""
    names = [f.relative_to(ds).as_posix() for f in files] + [TASKS_FILE]
    for row in rows:
        where = f"episode {row.get('episode_index')}"
        names.append(layout.data_path.format(chunk_index=_int(row, "data/chunk_index", where),
                                             file_index=_int(row, "data/file_index", where)))
        for cam in layout.cameras:
            key = image_key(cam)
            if layout.features[key]["dtype"] == "video":
                names.append(layout.video_path.format(video_key=key,
                                                      chunk_index=_int(row, f"videos/{key}/chunk_index", where),
                                                      file_index=_int(row, f"videos/{key}/file_index", where)))
    for name in dict.fromkeys(names):
        if name not in recorded:
            raise LeRobotFormatError(f"{ds}: meta/info.json records no checksum of {name}; export the dataset again")


@dataclass
class _PlannedEpisode:
    """One episode row of a dataset, checked, and the file it becomes."""

    row: dict[str, Any]
    meta: dict[str, Any]
    instruction: str
    path: Path


def _plan_episode(row: dict[str, Any], ds: Path, out: Path) -> _PlannedEpisode:
    """Check one episode row of an abm export (task, split, outcome, file name) and name its file."""
    where = f"{ds / EPISODES_FILE}: episode row {row.get('episode_index')}"
    try:
        meta = json.loads(row["abm/episode"])
        instruction = str(row["tasks"][0])
        task, split, seed = str(meta["task"]), str(meta["split"]), int(meta["seed"])
        success = meta["success"]
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise LeRobotFormatError(f"{where} is incomplete ({err!r})") from None
    trainable = sorted(name for name, cls in TASKS.items() if not cls.evaluation_only)
    if task not in trainable:
        raise LeRobotFormatError(f"{where}: task {task!r} is not an ABM-Bench task demonstrations exist for (known: "
                                 f"{', '.join(trainable)}); nothing was imported")
    if split not in SPLITS:
        raise LeRobotFormatError(f"{where}: split {split!r} is not one of {', '.join(SPLITS)}; nothing was imported")
    if success is not True:
        raise LeRobotFormatError(f"{where} is marked failed (success: {success!r}); abm stores only successful "
                                 "demonstrations: remove it from the dataset, nothing was imported")
    outdated = outdated_task_version(task, meta.get("metadata"))
    if outdated is not None:
        raise LeRobotFormatError(f"{where}: {outdated} Nothing was imported.")
    source = meta.get("source") or f"{task}/{split}/episode_{seed:06d}.h5"
    relative = PurePosixPath(str(source))
    path = out / relative
    if relative.is_absolute() or ".." in relative.parts or relative.suffix != ".h5" or not is_inside(path, out):
        raise LeRobotFormatError(f"{where}: its file name {source!r} would be written outside --out {out} (or is "
                                 "not a .h5 file name); nothing was imported: the dataset was not written by abm "
                                 "data export, or was edited")
    return _PlannedEpisode(row, meta, instruction, path)


def _plan_foreign(row: dict[str, Any], ds: Path, out: Path, task: str, split: str) -> _PlannedEpisode:
    """One episode row of a dataset not written by abm, and its file ``OUT/<task>/<split>/episode_<N>.h5``."""
    where = f"{ds}: episode row {row.get('episode_index')}"
    index = _int(row, "episode_index", where)
    tasks = row.get("tasks")
    if not isinstance(tasks, list) or not tasks or not str(tasks[0]).strip():
        raise LeRobotFormatError(f"{where} has no task string (the instruction abm trains on)")
    meta = {"task": task, "split": split, "lerobot_episode_index": index,
            "metadata": {"imported_from": "lerobot", "lerobot_dataset": ds.name, "lerobot_episode_index": index,
                         "keyframes": "detected (gripper changes, TCP at rest, last frame)"}}
    return _PlannedEpisode(row, meta, str(tasks[0]), out / task / split / f"episode_{index:06d}.h5")


def _check_targets(plan: list[_PlannedEpisode], out: Path, overwrite: bool) -> None:
    """Refuse an import that would replace episodes (or finish another import) unless ``overwrite``."""
    seen: dict[Path, int] = {}
    for i, item in enumerate(plan):
        if item.path in seen:
            raise LeRobotFormatError(f"episodes {seen[item.path]} and {i} of the dataset would both be written to "
                                     f"{item.path}; nothing was imported")
        seen[item.path] = i
    if overwrite:
        return
    if (out / IMPORT_MARKER).exists():
        raise OutputError(f"--out {out} holds an import that did not finish ({out / IMPORT_MARKER}); pass "
                          "--overwrite to import into it again (replacing the episodes it already wrote), or import "
                          "into a new folder")
    taken = [item.path for item in plan if item.path.exists() or item.path.is_symlink()]
    if taken:
        raise OutputError(f"--out {out} already holds {len(taken)} of the dataset's episodes (e.g. {taken[0]}); pass "
                          "--overwrite to replace them, or import into a new folder")


def _import_episodes(plan: list[_PlannedEpisode], reader: _FrameReader, layout: _Layout,
                     foreign: ForeignLayout | None, dense: bool, progress: bool) -> list[Path]:
    from tqdm import tqdm

    written: list[Path] = []
    for item in tqdm(plan, desc="import", unit="ep", disable=not progress):
        cols, rgb = reader.read(item.row)
        if foreign is not None:
            episode = foreign_episode(foreign, item.meta, item.instruction, cols, rgb, layout.fps)
        else:
            episode = _episode_from_columns(item.meta, item.instruction, cols, rgb, layout.cameras, dense,
                                            layout.fps)
        save_episode(episode, item.path)
        written.append(item.path)
    return written


def _episode_from_columns(meta: dict[str, Any], instruction: str, cols: dict[str, pa.ChunkedArray],
                          rgb: dict[str, np.ndarray], cameras: list[str], dense: bool, fps: float) -> Episode:
    """The abm episode of one exported episode (columns by their current names)."""
    n = len(cols["frame_index"])
    depth = {c: column_array(cols[depth_key(c)], [*rgb[c].shape[1:3]], np.float32) for c in cameras}
    seg = {c: (column_array(cols[segmentation_key(c)], [*rgb[c].shape[1:3]], np.int32)
               if segmentation_key(c) in cols else None) for c in cameras}
    intr = {c: column_array(cols[intrinsics_key(c)], [3, 3], np.float64) for c in cameras}
    extr = {c: column_array(cols[extrinsics_key(c)], [4, 4], np.float64) for c in cameras}
    state = column_array(cols[STATE_KEY], [8], np.float32)
    poses = column_array(cols[GRIPPER_POSE_KEY], [4, 4], np.float64)
    step = column_array(cols[STEP_KEY], [1], np.int64)
    observations = [Observation(
        cameras={c: CameraFrame(rgb=rgb[c][i], depth=depth[c][i], intrinsics=intr[c][i], extrinsics=extr[c][i],
                                segmentation=None if (s := seg[c]) is None else s[i]) for c in cameras},
        gripper_open=float(state[i, 7]), gripper_pose=poses[i], step=int(step[i])) for i in range(n)]
    flags = column_array(cols["keyframe.is_keyframe"], [1], bool)
    target = column_array(cols["keyframe.index"], [1], np.int64)
    pos = column_array(cols["keyframe.position"], [3], np.float64)
    quat = column_array(cols["keyframe.quaternion"], [4], np.float64)
    grip = column_array(cols["keyframe.gripper_open"], [1], bool)
    ignore = column_array(cols["keyframe.ignore_collision"], [1], bool)
    kinds = cols["keyframe.kind"].to_pylist()
    symmetry = column_array(cols["keyframe.symmetry"], [1], np.int64)
    frames = np.flatnonzero(flags)
    if not np.array_equal(target[frames], np.arange(len(frames))):
        raise LeRobotFormatError(f"episode {meta.get('source')}: keyframe flags and keyframe.index disagree")
    steps = [(observations[i], KeyframeAction(pos[i], quat[i], bool(grip[i]), bool(ignore[i]), kinds[i],
                                              int(symmetry[i]))) for i in frames]
    trajectory = None
    if dense:
        trajectory = Trajectory(fps=fps, observations=observations,
                                joint_positions=column_array(cols[JOINTS_KEY], [9], np.float64),
                                joint_actions=column_array(cols[ACTION_KEY], [8], np.float64),
                                ee_actions=column_array(cols[EE_ACTION_KEY], [8], np.float64), keyframe_frames=frames)
    try:
        return Episode(task=meta["task"], variation=int(meta["variation"]), split=meta["split"],
                       instruction=instruction, object_names={int(k): v for k, v in meta["object_names"].items()},
                       target_names=list(meta["target_names"]), steps=steps, success=bool(meta["success"]),
                       seed=int(meta["seed"]), metadata=meta.get("metadata", {}), trajectory=trajectory)
    except (KeyError, TypeError, ValueError) as err:
        raise LeRobotFormatError(f"episode {meta.get('source')}: metadata incomplete ({err!r})") from None
