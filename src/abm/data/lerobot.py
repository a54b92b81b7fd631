"""abm episodes <-> LeRobot datasets (``abm data export --format lerobot`` / ``abm data import``).

Writes the LeRobot **v3.0** layout (``codebase_version`` "v3.0", the layout of lerobot 0.4)::

    DS/meta/info.json                                 features (dtype, shape, names), fps, counts, paths
    DS/meta/stats.json                                mean / std / min / max / count per feature
    DS/meta/tasks.parquet                             task string (the instruction) -> task_index
    DS/meta/episodes/chunk-000/file-000.parquet       one row per episode: length, frame range, video ranges,
                                                      and ``abm/episode`` (JSON: task, split, seed, objects, ...)
    DS/data/chunk-000/file-000.parquet                one row per frame, one row group per episode
    DS/videos/observation.images.<camera>/chunk-000/file-000.mp4   all episodes of a camera, back to back

A frame is a dense control tick (episodes generated with ``--dense``) or, for keyframe-only episodes, a
keyframe (then ``fps`` is a nominal 1 and ``action`` is the keyframe target). Depth and segmentation go
into the parquet as float32 / int32 ``(H, W)`` arrays (lossless; mp4 codecs are not), and the camera
calibration as float64 ``(3, 3)`` intrinsics and ``(4, 4)`` camera-to-world extrinsics per frame, so the
point cloud can be rebuilt. RGB is H.264 (yuv420p) and therefore lossy: an import gives the images back
within codec tolerance and everything else exactly (actions of dense frames are float32).

Integrity and containment: the export checks every episode's checksums before it writes anything, records
the sha256 of its parquet and video files in ``meta/info.json`` (``abm.sha256``), and on failure removes only
what it created. The import checks those sha256, refuses episodes marked failed, unknown tasks and file names
that leave ``--out``, replaces existing episodes only with ``overwrite``, and marks ``--out`` with
``.import-incomplete`` until the last episode is written.
"""

from __future__ import annotations

import json
import logging
import os
import shlex
import shutil
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import DTypeLike, NDArray

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
from abm.files import is_inside, sha256_file, write_text_atomic
from abm.geometry.rotations import matrix_to_quat
from abm.sim.tasks import TASKS
from abm.types import CameraFrame, Episode, KeyframeAction, Observation, Trajectory

if TYPE_CHECKING:  # pyarrow is imported where datasets are written or read
    import pyarrow as pa

CODEBASE_VERSION = "v3.0"
KEYFRAME_FPS = 1.0  # nominal rate of keyframe-only exports
DATA_FILE = "data/chunk-000/file-000.parquet"
EPISODES_FILE = "meta/episodes/chunk-000/file-000.parquet"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
STATE_NAMES = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open"]
JOINT_NAMES = [f"joint{i}" for i in range(1, 8)] + ["finger_left", "finger_right"]
JOINT_ACTION_NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]
EE_ACTION_NAMES = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper"]
EXPORT_MARKER = ".export-incomplete"  # in a dataset folder while abm data export writes it
_EXPORT_ENTRIES = ("data", "meta", "videos")  # what an export creates in its --out folder (besides the marker)


class LeRobotFormatError(ValueError):
    """A dataset folder that is not a LeRobot v3 dataset abm can import (the message says why)."""


@dataclass
class ExportReport:
    episodes: int
    frames: int
    fps: float
    dense: bool
    bytes: int


def _image_key(camera: str) -> str:
    return f"observation.images.{camera}"


def _features(cameras: list[str], size: tuple[int, int], dense: bool, segmentation: bool, fps: float,
              crf: int) -> dict[str, dict[str, Any]]:
    h, w = size
    feats: dict[str, dict[str, Any]] = {}
    for cam in cameras:
        feats[_image_key(cam)] = {
            "dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channels"],
            "info": {"video.height": h, "video.width": w, "video.codec": "h264", "video.pix_fmt": "yuv420p",
                     "video.is_depth_map": False, "video.fps": fps, "video.channels": 3, "video.crf": crf,
                     "has_audio": False}}
        feats[f"observation.depth.{cam}"] = {"dtype": "float32", "shape": [h, w], "names": ["height", "width"],
                                             "info": {"unit": "m, along the camera +z axis; 0 = no measurement"}}
        if segmentation:
            feats[f"observation.segmentation.{cam}"] = {"dtype": "int32", "shape": [h, w],
                                                        "names": ["height", "width"],
                                                        "info": {"values": "object id (abm/episode object_names), "
                                                                           "-1 = none"}}
        feats[f"observation.intrinsics.{cam}"] = {"dtype": "float64", "shape": [3, 3], "names": None,
                                                  "info": {"convention": "OpenCV pinhole, pixels"}}
        feats[f"observation.extrinsics.{cam}"] = {"dtype": "float64", "shape": [4, 4], "names": None,
                                                  "info": {"convention": "camera-to-world, OpenCV camera axes"}}
    feats["observation.state"] = {"dtype": "float32", "shape": [8], "names": STATE_NAMES,
                                  "info": {"meaning": "TCP position (m) and orientation in the robot base frame, "
                                                      "gripper opening in [0, 1]"}}
    feats["observation.gripper_pose"] = {"dtype": "float64", "shape": [4, 4], "names": None}
    feats["observation.step"] = {"dtype": "int64", "shape": [1], "names": None}
    if dense:
        feats["observation.joint_positions"] = {"dtype": "float64", "shape": [9], "names": JOINT_NAMES}
        feats["action"] = {"dtype": "float32", "shape": [8], "names": JOINT_ACTION_NAMES,
                           "info": {"meaning": "arm joint servo targets (rad) and gripper command (1 = open) "
                                               "of the next control tick"}}
        feats["action.ee"] = {"dtype": "float32", "shape": [8], "names": EE_ACTION_NAMES,
                              "info": {"meaning": "TCP pose of the next control tick and gripper command"}}
    else:
        feats["action"] = {"dtype": "float32", "shape": [8], "names": EE_ACTION_NAMES,
                           "info": {"meaning": "the next keyframe: TCP target and gripper open"}}
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
    for key in ("timestamp",):
        feats[key] = {"dtype": "float32", "shape": [1], "names": None}
    for key in ("frame_index", "episode_index", "index", "task_index"):
        feats[key] = {"dtype": "int64", "shape": [1], "names": None}
    return feats


def _arrow_type(feature: dict[str, Any]) -> pa.DataType:
    import pyarrow as pa

    base = {"float32": pa.float32(), "float64": pa.float64(), "int32": pa.int32(), "int64": pa.int64(),
            "bool": pa.bool_(), "string": pa.string()}[feature["dtype"]]
    shape = feature["shape"]
    if shape == [1]:
        return base
    for n in reversed(shape):
        base = pa.list_(base, n)
    return base


def _column(feature: dict[str, Any], values: np.ndarray | list[str]) -> pa.Array:
    import pyarrow as pa

    typ = _arrow_type(feature)
    if feature["shape"] == [1]:
        return pa.array(values, type=typ)
    arr = np.ascontiguousarray(values)
    flat = pa.array(arr.reshape(-1), type=typ.value_type if len(feature["shape"]) == 1 else None)
    out = flat
    for n in reversed(feature["shape"]):
        out = pa.FixedSizeListArray.from_arrays(out, n)
    return out


class _Stats:
    """Running mean / std / min / max of one feature (over frames; per element for vectors, per channel for
    videos, over everything for 2-D arrays)."""

    def __init__(self) -> None:
        self.n = 0
        self.sum: NDArray[np.float64] | None = None
        self.sq: NDArray[np.float64] | None = None
        self.min: NDArray[np.float64] | None = None
        self.max: NDArray[np.float64] | None = None

    def add(self, values: np.ndarray, axes: tuple[int, ...]) -> None:
        v = np.asarray(values, np.float64)
        s, q = v.sum(axis=axes), (v * v).sum(axis=axes)
        lo, hi = v.min(axis=axes), v.max(axis=axes)
        count = int(np.prod([v.shape[a] for a in axes]))
        if self.sum is None or self.sq is None or self.min is None or self.max is None:  # the first add
            self.sum, self.sq, self.min, self.max = s, q, lo, hi
        else:
            self.sum, self.sq = self.sum + s, self.sq + q
            self.min, self.max = np.minimum(self.min, lo), np.maximum(self.max, hi)
        self.n += count

    def result(self, shape: tuple[int, ...]) -> dict[str, list[Any]]:
        assert self.sum is not None and self.sq is not None, "no values were added"
        mean = self.sum / self.n
        std = np.sqrt(np.maximum(self.sq / self.n - mean * mean, 0.0))
        return {k: np.asarray(v).reshape(shape).tolist() for k, v in
                (("mean", mean), ("std", std), ("min", self.min), ("max", self.max))} | {"count": [self.n]}


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
                   robot_type: str = "franka_panda", progress: bool = True) -> ExportReport:
    """Write every episode under ``data`` as one LeRobot v3 dataset in ``out`` (a new or empty folder).

    Args:
        frames: ``"dense"`` (the ``--dense`` trajectories), ``"keyframes"``, or ``"auto"`` (dense when every
            episode has a trajectory).
        crf: H.264 quality of the camera videos (0 = best, 51 = worst; 18 is visually lossless).
    """
    import av  # noqa: F401 - a missing video library fails here, before anything is written
    import pyarrow as pa

    data, out = Path(data), Path(out)
    if not data.is_dir():
        raise FileNotFoundError(f"--data {data} is not a folder of abm episodes")
    _check_export_target(out)
    if frames not in ("auto", "dense", "keyframes"):
        raise ValueError(f"--frames must be auto, dense or keyframes, got {frames!r}")
    if not 0 <= crf <= 51:
        raise ValueError(f"--crf must be between 0 and 51, got {crf}")
    store = EpisodeStore(data)
    if not len(store):
        raise ValueError(f"no abm episodes (*.h5) under {data}")
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
    if size[0] % 2 or size[1] % 2:
        raise ValueError(f"the episodes' images are {size[0]}x{size[1]}; H.264 video (yuv420p) needs even sizes")
    segmentation = all(c.segmentation is not None for c in first.steps[0][0].cameras.values())
    dense_all = all("dense_fps" in _metadata(i.path) for i in store.episodes)
    if frames == "dense" and not dense_all:
        missing = next(i.path for i in store.episodes if "dense_fps" not in _metadata(i.path))
        raise ValueError(f"--frames dense: {missing} has no dense trajectory (generate with --dense)")
    dense = frames == "dense" or (frames == "auto" and dense_all)
    fps = float(first.trajectory.fps) if dense and first.trajectory is not None else KEYFRAME_FPS
    features = _features(cameras, size, dense, segmentation, fps, crf)
    schema = pa.schema([(k, _arrow_type(f)) for k, f in features.items() if f["dtype"] != "video"])

    created = _first_missing(out)  # everything from here down is this export's own, removed if it fails
    try:
        out.mkdir(parents=True, exist_ok=True)
        return _write_export(store, first, out, cameras, size, segmentation, dense, fps, features, schema, crf,
                             robot_type, progress)
    except BaseException:
        _remove_export(out, created)
        raise


def _check_export_target(out: Path) -> None:
    """``--out`` must be a new or an empty folder (an export never replaces or mixes with other files)."""
    if out.is_symlink() and not out.exists():
        raise ValueError(f"--out {out} is a symbolic link to a missing folder; give a new folder")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not an empty folder (it is a file); give a new folder")
    if out.is_dir() and any(out.iterdir()):
        if (out / EXPORT_MARKER).exists():
            raise ValueError(f"--out {out} exists and is not an empty folder: it holds an export that did not "
                             f"finish ({out / EXPORT_MARKER}); delete that folder yourself and export again, or "
                             "give a new folder")
        raise ValueError(f"--out {out} exists and is not an empty folder; give a new folder")


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


def _write_export(store: EpisodeStore, first: Episode, out: Path, cameras: list[str], size: tuple[int, int],
                  segmentation: bool, dense: bool, fps: float, features: dict[str, dict[str, Any]],
                  schema: pa.Schema, crf: int, robot_type: str, progress: bool) -> ExportReport:
    """Write the dataset into the (empty) folder ``out``; see :func:`export_lerobot`."""
    import av
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    data = store.root
    tmp = out / EXPORT_MARKER
    tmp.write_text("abm data export is writing this dataset\n")
    (out / DATA_FILE).parent.mkdir(parents=True, exist_ok=True)
    writer = pq.ParquetWriter(out / DATA_FILE, schema, compression="zstd")
    containers, streams = {}, {}
    rate = Fraction(fps).limit_denominator(1000)
    for cam in cameras:
        path = out / VIDEO_PATH.format(video_key=_image_key(cam), chunk_index=0, file_index=0)
        path.parent.mkdir(parents=True, exist_ok=True)
        containers[cam] = av.open(str(path), "w")
        stream = containers[cam].add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = size[1], size[0], "yuv420p"
        stream.time_base = 1 / rate
        stream.options = {"crf": str(crf), "g": "10"}
        streams[cam] = stream
    stats = {k: _Stats() for k, f in features.items() if f["dtype"] not in ("string", "bool")}
    tasks: dict[str, int] = {}
    episode_rows: list[dict[str, Any]] = []
    total = 0
    for ep_index, info in enumerate(tqdm(store.episodes, desc="export", unit="ep", disable=not progress)):
        episode = load_episode(info.path) if ep_index else first
        if dense:
            if episode.trajectory is None:
                raise ValueError(f"{info.path} has no dense trajectory (generate with --dense)")
            if abs(episode.trajectory.fps - fps) > 1e-9:
                raise ValueError(
                    f"{info.path} was recorded at {episode.trajectory.fps} fps, the first episode at {fps}")
        observations, target, flags = _frames_of(episode, dense)
        n = len(observations)
        task_index = tasks.setdefault(episode.instruction, len(tasks))
        actions = [a for _, a in episode.steps]
        cols: dict[str, np.ndarray | list[str]] = {}
        for cam in cameras:
            cf = [o.cameras[cam] for o in observations]
            cols[f"observation.depth.{cam}"] = np.stack([c.depth for c in cf]).astype(np.float32)
            if segmentation:
                # every frame has one when the first has (a missing one fails in np.stack)
                segs = cast("list[np.ndarray]", [c.segmentation for c in cf])
                cols[f"observation.segmentation.{cam}"] = np.stack(segs).astype(np.int32)
            cols[f"observation.intrinsics.{cam}"] = np.stack([c.intrinsics for c in cf])
            cols[f"observation.extrinsics.{cam}"] = np.stack([c.extrinsics for c in cf])
            rgb = np.stack([c.rgb for c in cf])
            for i, img in enumerate(rgb):
                frame = av.VideoFrame.from_ndarray(img, format="rgb24")
                frame.pts = total + i
                for packet in streams[cam].encode(frame):
                    containers[cam].mux(packet)
            stats[_image_key(cam)].add(rgb / 255.0, (0, 1, 2))
        poses = np.stack([o.gripper_pose for o in observations])

        cols["observation.state"] = np.concatenate(
            [poses[:, :3, 3], matrix_to_quat(poses[:, :3, :3]),
             np.array([[o.gripper_open] for o in observations])], axis=1).astype(np.float32)
        cols["observation.gripper_pose"] = poses
        cols["observation.step"] = np.array([o.step for o in observations], np.int64)
        kf_pos = np.array([actions[k].position for k in target]).reshape(n, 3)
        kf_quat = np.array([actions[k].quaternion for k in target]).reshape(n, 4)
        kf_open = np.array([actions[k].gripper_open for k in target], bool)
        if dense:
            traj = episode.trajectory
            assert traj is not None  # checked above
            cols["observation.joint_positions"] = traj.joint_positions
            cols["action"] = traj.joint_actions.astype(np.float32)
            cols["action.ee"] = traj.ee_actions.astype(np.float32)
        else:
            cols["action"] = np.concatenate([kf_pos, kf_quat, kf_open[:, None]], axis=1).astype(np.float32)
        cols["keyframe.is_keyframe"] = flags
        cols["keyframe.index"] = target.astype(np.int64)
        cols["keyframe.position"] = kf_pos
        cols["keyframe.quaternion"] = kf_quat
        cols["keyframe.gripper_open"] = kf_open
        cols["keyframe.ignore_collision"] = np.array([actions[k].ignore_collision for k in target], bool)
        cols["keyframe.kind"] = [actions[k].kind for k in target]
        cols["keyframe.symmetry"] = np.array([actions[k].symmetry for k in target], np.int64)
        cols["frame_index"] = np.arange(n, dtype=np.int64)
        cols["timestamp"] = (np.arange(n) / fps).astype(np.float32)
        cols["episode_index"] = np.full(n, ep_index, np.int64)
        cols["index"] = np.arange(total, total + n, dtype=np.int64)
        cols["task_index"] = np.full(n, task_index, np.int64)
        writer.write_table(pa.table({k: _column(features[k], cols[k]) for k in schema.names}, schema=schema))
        for k, st in stats.items():
            if features[k]["dtype"] == "video":
                continue
            v = np.asarray(cols[k], np.float64)
            st.add(v.reshape(n, -1) if v.ndim <= 2 else v, (0,) if v.ndim <= 2 else tuple(range(v.ndim)))
        meta = {"task": episode.task, "split": episode.split, "variation": episode.variation,
                "object_names": {str(k): v for k, v in episode.object_names.items()},
                "target_names": list(episode.target_names), "success": bool(episode.success),
                "seed": int(episode.seed), "metadata": episode.metadata, "cameras": cameras,
                "source": _source_name(info.path, data), "frames": "dense" if dense else "keyframes"}
        row: dict[str, Any] = {"episode_index": ep_index, "tasks": [episode.instruction], "length": n,
                               "data/chunk_index": 0, "data/file_index": 0, "dataset_from_index": total,
                               "dataset_to_index": total + n}
        for cam in cameras:
            key = _image_key(cam)
            row |= {f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
                    f"videos/{key}/from_timestamp": total / fps, f"videos/{key}/to_timestamp": (total + n) / fps}
        row |= {"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                "abm/episode": json.dumps(meta, default=_json_default)}
        episode_rows.append(row)
        total += n
    writer.close()
    for cam in cameras:
        for packet in streams[cam].encode():
            containers[cam].mux(packet)
        containers[cam].close()

    (out / EPISODES_FILE).parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(episode_rows), out / EPISODES_FILE)
    _write_tasks(out / "meta" / "tasks.parquet", tasks)
    shapes = {k: ([3, 1, 1] if f["dtype"] == "video" else (f["shape"] if len(f["shape"]) == 1 else [1]))
              for k, f in features.items()}
    (out / "meta" / "stats.json").write_text(json.dumps(
        {k: st.result(tuple(shapes[k])) for k, st in stats.items() if st.n}, indent=1))
    info_json = {
        "codebase_version": CODEBASE_VERSION, "robot_type": robot_type, "total_episodes": len(episode_rows),
        "total_frames": total, "total_tasks": len(tasks), "chunks_size": 1000,
        "data_files_size_in_mb": 100, "video_files_size_in_mb": 500, "fps": int(fps) if fps.is_integer() else fps,
        "splits": {"train": f"0:{len(episode_rows)}"}, "data_path": DATA_PATH, "video_path": VIDEO_PATH,
        "features": features,
        "abm": {"frames": "dense" if dense else "keyframes", "cameras": cameras,
                "written_by": "abm data export --format lerobot",
                "sha256": {name: sha256_file(out / name) for name in _checked_files(cameras)},
                "note": "depth, segmentation and calibration are parquet columns; RGB is H.264 mp4"}}
    (out / "meta" / "info.json").write_text(json.dumps(info_json, indent=2))
    tmp.unlink()
    size_bytes = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return ExportReport(len(episode_rows), total, fps, dense, size_bytes)


def _checked_files(cameras: list[str]) -> list[str]:
    """The files of a dataset whose sha256 the export records in ``meta/info.json`` (``abm.sha256``) and the
    import checks: the frames, the episode and task tables and the videos."""
    return [DATA_FILE, EPISODES_FILE, "meta/tasks.parquet",
            *(VIDEO_PATH.format(video_key=_image_key(c), chunk_index=0, file_index=0) for c in cameras)]


def _metadata(path: Path) -> dict[str, Any]:
    return load_metadata(path)


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


# --- import ---------------------------------------------------------------------------------------


def _read_json(path: Path, what: str) -> dict[str, Any]:
    if not path.is_file():
        raise LeRobotFormatError(f"{path.parent.parent}: not a LeRobot dataset ({what} {path} is missing)")
    try:
        data: dict[str, Any] = json.loads(path.read_text())
        return data
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise LeRobotFormatError(f"{path}: not valid JSON ({err})") from None


def _read_parquet(path: Path) -> pa.Table:
    import pyarrow.parquet as pq

    if not path.is_file():
        raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
    try:
        return pq.read_table(path)
    except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
        raise LeRobotFormatError(f"{path}: not a readable parquet file ({err})") from None


class _VideoFrames:
    """The frames of one camera's mp4, read in order, one episode at a time (constant memory)."""

    def __init__(self, path: Path, fps: float) -> None:
        import av

        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        self.path, self.fps, self.next = path, fps, 0
        try:
            self._container = av.open(str(path))
            self._frames = self._container.decode(video=0)
        except av.error.FFmpegError as err:
            raise LeRobotFormatError(f"{path}: not a readable video ({err})") from None

    def take(self, lo: int, hi: int) -> np.ndarray:
        """Frames ``lo`` to ``hi - 1`` (``lo`` must be where the previous call stopped)."""
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
    """Rows of the frame parquet read row group by row group (one per episode as written), in order."""

    def __init__(self, path: Path) -> None:
        import pyarrow.parquet as pq

        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        try:
            self.file = pq.ParquetFile(path)
        except Exception as err:  # noqa: BLE001 - pyarrow raises several types for damaged files
            raise LeRobotFormatError(f"{path}: not a readable parquet file ({err})") from None
        self.path, self.group, self.start = path, 0, 0
        self.buffer: pa.Table | None = None
        self.column_names = self.file.schema_arrow.names
        self.num_rows = self.file.metadata.num_rows

    def take(self, lo: int, hi: int) -> pa.Table:
        import pyarrow as pa

        while self.buffer is None or self.start + self.buffer.num_rows < hi:
            if self.group >= self.file.num_row_groups:
                raise LeRobotFormatError(f"{self.path}: rows {lo} to {hi - 1} are missing")
            part = self.file.read_row_group(self.group)
            self.group += 1
            self.buffer = part if self.buffer is None else pa.concat_tables([self.buffer, part])
        rows = self.buffer.slice(lo - self.start, hi - lo)
        self.buffer, self.start = self.buffer.slice(hi - self.start), hi
        return rows


def import_lerobot(dataset: str | os.PathLike[str], out: str | os.PathLike[str], progress: bool = True,
                   overwrite: bool = False) -> list[Path]:
    """Read a LeRobot v3 dataset written by :func:`export_lerobot` back into abm episode files under ``out``
    (``OUT/<task>/<split>/episode_<seed>.h5``, as ``abm data generate`` lays them out). Returns the files.
    Frames and videos are read episode by episode, so memory does not grow with the dataset.

    Nothing is written before the whole dataset has been checked: the files against the sha256 the export
    recorded, every episode's task (a trainable ABM-Bench task), split and outcome (only successful
    demonstrations), and every episode's file name, which must stay inside ``out``. While episodes are written
    ``OUT/.import-incomplete`` marks the folder as partial (:func:`abm.data.episode_store.check_complete`);
    it is removed when the last episode is written, so an import that fails or is stopped stays marked.

    Args:
        overwrite: replace episode files that ``out`` already holds (without it such an import is refused).

    Raises:
        LeRobotFormatError: the dataset is not one abm can import, or fails a check above.
        ValueError: ``out`` already holds some of the episodes (or an unfinished import) and not ``overwrite``.
    """
    ds, out = Path(dataset), Path(out)
    if not ds.is_dir():
        raise FileNotFoundError(f"LeRobot dataset folder not found: {ds}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder")
    info = _read_json(ds / "meta" / "info.json", "meta/info.json")
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise LeRobotFormatError(f"{ds}: LeRobot dataset version {version!r}; abm reads {CODEBASE_VERSION!r} "
                                 "(convert older datasets with lerobot's v2.1 -> v3.0 converter)")
    features = info.get("features")
    abm_info = info.get("abm")
    if not isinstance(features, dict) or not isinstance(abm_info, dict):
        raise LeRobotFormatError(f"{ds}: meta/info.json has no abm section; only datasets written by `abm data "
                                 "export` carry the depth, calibration and keyframe columns an abm episode needs")
    try:
        fps = float(info["fps"])
        cameras = list(abm_info["cameras"])
        dense = abm_info["frames"] == "dense"
        if any(len(features[_image_key(c)]["shape"]) != 3 for c in cameras):
            raise ValueError("camera features must have shape [height, width, 3]")
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise LeRobotFormatError(f"{ds}: meta/info.json is incomplete ({err!r})") from None
    if (ds / EXPORT_MARKER).exists():
        raise LeRobotFormatError(f"{ds}: the export did not finish (remove the folder and export again)")
    _verify_dataset_files(ds, abm_info, cameras)
    episodes = sorted(_read_parquet(ds / EPISODES_FILE).to_pylist(), key=lambda r: r.get("dataset_from_index", 0))
    plan = [_plan_episode(row, ds, out) for row in episodes]
    _check_targets(plan, out, overwrite)
    table = _Rows(ds / DATA_FILE)
    missing = [k for k, f in features.items() if f.get("dtype") != "video" and k not in table.column_names]
    if missing:
        raise LeRobotFormatError(f"{ds / DATA_FILE}: columns {missing} listed in meta/info.json are missing")
    videos = {cam: _VideoFrames(ds / VIDEO_PATH.format(video_key=_image_key(cam), chunk_index=0, file_index=0), fps)
              for cam in cameras}
    try:
        out.mkdir(parents=True, exist_ok=True)
        marker = out / IMPORT_MARKER
        redo = f"abm data import --format lerobot {shlex.quote(str(ds))} --out {shlex.quote(str(out))} --overwrite"
        write_text_atomic(marker, f"{redo}\nabm data import is writing this folder; until it finishes, the folder "
                                  "holds only part of the dataset\n")
        written = _import_episodes(plan, table, videos, cameras, dense, fps, progress)
        marker.unlink()
        return written
    finally:
        for v in videos.values():
            v.close()


def _verify_dataset_files(ds: Path, abm_info: dict[str, Any], cameras: list[str]) -> None:
    """Compare the dataset's files with the sha256 the export recorded (datasets written before abm recorded
    them are read as they are, with a warning)."""
    recorded = abm_info.get("sha256")
    if recorded is None:
        logging.getLogger("abm").warning("%s: written by an abm export that recorded no checksums; its files "
                                         "cannot be verified", ds)
        return
    if not isinstance(recorded, dict):
        raise LeRobotFormatError(f"{ds}: meta/info.json abm.sha256 is not a mapping of file names to checksums")
    for name in _checked_files(cameras):
        path = ds / name
        if name not in recorded:
            raise LeRobotFormatError(f"{ds}: meta/info.json records no checksum of {name}; export the dataset again")
        if not path.is_file():
            raise LeRobotFormatError(f"{path} is missing (the dataset is incomplete)")
        if sha256_file(path) != recorded[name]:
            raise LeRobotFormatError(f"{path} does not match the checksum the export recorded; the dataset is "
                                     "corrupt: export it again from the abm episodes")


@dataclass
class _PlannedEpisode:
    """One episode row of a dataset, checked, and the file it becomes."""

    row: dict[str, Any]
    meta: dict[str, Any]
    instruction: str
    lo: int
    hi: int
    path: Path


def _plan_episode(row: dict[str, Any], ds: Path, out: Path) -> _PlannedEpisode:
    """Check one episode row (task, split, outcome, file name) and name the file it is imported into."""
    where = f"{ds / EPISODES_FILE}: episode row {row.get('episode_index')}"
    try:
        meta = json.loads(row["abm/episode"])
        lo, hi = int(row["dataset_from_index"]), int(row["dataset_to_index"])
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
    return _PlannedEpisode(row, meta, instruction, lo, hi, path)


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
        raise ValueError(f"--out {out} holds an import that did not finish ({out / IMPORT_MARKER}); pass "
                         "--overwrite to import into it again (replacing the episodes it already wrote), or import "
                         "into a new folder")
    taken = [item.path for item in plan if item.path.exists() or item.path.is_symlink()]
    if taken:
        raise ValueError(f"--out {out} already holds {len(taken)} of the dataset's episodes (e.g. {taken[0]}); pass "
                         "--overwrite to replace them, or import into a new folder")


def _import_episodes(plan: list[_PlannedEpisode], table: _Rows, videos: dict[str, _VideoFrames],
                     cameras: list[str], dense: bool, fps: float, progress: bool) -> list[Path]:
    from tqdm import tqdm

    written: list[Path] = []
    for item in tqdm(plan, desc="import", unit="ep", disable=not progress):
        rows = table.take(item.lo, item.hi)
        cols = {k: rows.column(k) for k in rows.column_names}
        episode = _episode_from_columns(item.meta, item.instruction, cols,
                                        {c: v.take(item.lo, item.hi) for c, v in videos.items()}, cameras, dense, fps)
        save_episode(episode, item.path)
        written.append(item.path)
    return written


def _np(col: pa.ChunkedArray, shape: list[int], dtype: DTypeLike) -> np.ndarray:
    n = len(col)
    if shape == [1]:
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype)
    flat = col.combine_chunks()
    for _ in shape:
        flat = flat.flatten()
    return np.asarray(flat.to_numpy(zero_copy_only=False), dtype).reshape(n, *shape)


def _episode_from_columns(meta: dict[str, Any], instruction: str, cols: dict[str, pa.ChunkedArray],
                          rgb: dict[str, np.ndarray], cameras: list[str], dense: bool, fps: float) -> Episode:
    n = len(cols["frame_index"])
    depth = {c: _np(cols[f"observation.depth.{c}"], [*rgb[c].shape[1:3]], np.float32) for c in cameras}
    seg = {c: (_np(cols[f"observation.segmentation.{c}"], [*rgb[c].shape[1:3]], np.int32)
               if f"observation.segmentation.{c}" in cols else None) for c in cameras}
    intr = {c: _np(cols[f"observation.intrinsics.{c}"], [3, 3], np.float64) for c in cameras}
    extr = {c: _np(cols[f"observation.extrinsics.{c}"], [4, 4], np.float64) for c in cameras}
    state = _np(cols["observation.state"], [8], np.float32)
    poses = _np(cols["observation.gripper_pose"], [4, 4], np.float64)
    step = _np(cols["observation.step"], [1], np.int64)
    observations = [Observation(
        cameras={c: CameraFrame(rgb=rgb[c][i], depth=depth[c][i], intrinsics=intr[c][i], extrinsics=extr[c][i],
                                segmentation=None if (s := seg[c]) is None else s[i]) for c in cameras},
        gripper_open=float(state[i, 7]), gripper_pose=poses[i], step=int(step[i])) for i in range(n)]
    flags = _np(cols["keyframe.is_keyframe"], [1], bool)
    target = _np(cols["keyframe.index"], [1], np.int64)
    pos = _np(cols["keyframe.position"], [3], np.float64)
    quat = _np(cols["keyframe.quaternion"], [4], np.float64)
    grip = _np(cols["keyframe.gripper_open"], [1], bool)
    ignore = _np(cols["keyframe.ignore_collision"], [1], bool)
    kinds = cols["keyframe.kind"].to_pylist()
    symmetry = _np(cols["keyframe.symmetry"], [1], np.int64)
    frames = np.flatnonzero(flags)
    if not np.array_equal(target[frames], np.arange(len(frames))):
        raise LeRobotFormatError(f"episode {meta.get('source')}: keyframe flags and keyframe.index disagree")
    steps = [(observations[i], KeyframeAction(pos[i], quat[i], bool(grip[i]), bool(ignore[i]), kinds[i],
                                              int(symmetry[i]))) for i in frames]
    trajectory = None
    if dense:
        trajectory = Trajectory(fps=fps, observations=observations,
                                joint_positions=_np(cols["observation.joint_positions"], [9], np.float64),
                                joint_actions=_np(cols["action"], [8], np.float64),
                                ee_actions=_np(cols["action.ee"], [8], np.float64), keyframe_frames=frames)
    try:
        return Episode(task=meta["task"], variation=int(meta["variation"]), split=meta["split"],
                       instruction=instruction, object_names={int(k): v for k, v in meta["object_names"].items()},
                       target_names=list(meta["target_names"]), steps=steps, success=bool(meta["success"]),
                       seed=int(meta["seed"]), metadata=meta.get("metadata", {}), trajectory=trajectory)
    except (KeyError, TypeError, ValueError) as err:
        raise LeRobotFormatError(f"episode {meta.get('source')}: metadata incomplete ({err!r})") from None
