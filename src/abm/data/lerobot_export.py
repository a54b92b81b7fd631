"""abm episodes -> a LeRobot v3.0 dataset (``abm data export --format lerobot``): :func:`export_lerobot`.

The layout and the features are described in :mod:`abm.data.lerobot` and :mod:`abm.data.lerobot_schema`. Files
are split like LeRobot's: a data file is closed before an episode would take it past ``data_files_size_in_mb``
(judged by the file's bytes per frame so far), a video file before an episode's encoded video would take it past
``video_files_size_in_mb`` (each episode is encoded on its own, then appended); an episode is never split across
files. The export checks every episode's checksums before it writes anything, records the sha256 of every parquet
and video file in ``meta/info.json`` (``abm.sha256``), and on failure removes only what it created. The reader is
:mod:`abm.data.lerobot_import`.
"""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from abm.data.episode_store import (
    EpisodeFormatError,
    EpisodeStore,
    check_episodes,
    load_episode,
    load_metadata,
)
from abm.data.lerobot_schema import (
    ABM_FORMAT,
    ACTION_KEY,
    CHUNKS_SIZE,
    CODEBASE_VERSION,
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
    STATE_KEY,
    STATE_NAMES,
    STEP_KEY,
    TASKS_FILE,
    VIDEO_FILE_MB,
    VIDEO_PATH,
    depth_key,
    extrinsics_key,
    image_key,
    intrinsics_key,
    segmentation_key,
)
from abm.data.lerobot_stats import aggregate_stats, feature_stats
from abm.errors import ConfigError, DataError, OutputError
from abm.files import sha256_file
from abm.geometry.rotations import matrix_to_quat
from abm.types import Episode, Observation

if TYPE_CHECKING:  # pyarrow is imported where datasets are written or read
    import pyarrow as pa


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
