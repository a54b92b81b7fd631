"""A LeRobot dataset -> abm episodes (``abm data import --format lerobot``): :func:`import_lerobot`.

A dataset written by :func:`abm.data.lerobot_export.export_lerobot` comes back as it was exported (the layout:
:mod:`abm.data.lerobot`). The import checks the sha256 the export recorded, refuses episodes marked failed, unknown
tasks and file names that leave ``--out``, replaces existing episodes only with ``overwrite``, and marks ``--out``
with ``.import-incomplete`` until the last episode is written. Datasets not written by abm are read through
:mod:`abm.data.lerobot_foreign` (they need depth and calibration).
"""

from __future__ import annotations

import io
import json
import logging
import os
import shlex
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

import numpy as np

from abm.configuration import SPLITS
from abm.data.episode_store import (
    IMPORT_MARKER,
    outdated_task_version,
    save_episode,
)
from abm.data.lerobot_foreign import ForeignLayout, foreign_episode, foreign_layout
from abm.data.lerobot_schema import (
    ABM_FORMAT,
    ACTION_KEY,
    CODEBASE_VERSION,
    DATA_PATH,
    EE_ACTION_KEY,
    EPISODES_FILE,
    EXPORT_MARKER,
    GRIPPER_POSE_KEY,
    JOINTS_KEY,
    NOT_NUMBERS,
    STATE_KEY,
    STEP_KEY,
    TASKS_FILE,
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
from abm.errors import ConfigError, OutputError
from abm.files import is_inside, sha256_file, write_text_atomic
from abm.sim.tasks import TASKS
from abm.types import CameraFrame, Episode, KeyframeAction, Observation, Trajectory

if TYPE_CHECKING:  # pyarrow is imported where datasets are written or read
    import pyarrow as pa


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

    A dataset written by :func:`~abm.data.lerobot_export.export_lerobot` (either format) comes back as it was
    exported. Any other LeRobot v3 dataset needs depth and calibration per camera and the gripper pose and opening
    per frame (:mod:`abm.data.lerobot_foreign`), and ``task`` (and ``split``, default ``"seen"``), which it cannot
    name.

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
