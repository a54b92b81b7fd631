"""On-disk episodes: one HDF5 file per :class:`abm.types.Episode`.

File layout (``FORMAT_VERSION`` 2); ``K`` keyframes, per camera ``H x W`` pixels::

    /                       attrs: format_version, task, split, variation, instruction, success, seed,
                                   num_keyframes, object_names (JSON {id: name}), target_names (JSON),
                                   camera_names (JSON), metadata (JSON)
    /observations/gripper_open   (K,)       float32
    /observations/gripper_pose   (K, 4, 4)  float64
    /observations/step           (K,)       int64
    /observations/cameras/<name>/rgb           (K, H, W, 3) uint8    gzip, one chunk per keyframe
    /observations/cameras/<name>/depth         (K, H, W)    float32  gzip, metres along +z
    /observations/cameras/<name>/segmentation  (K, H, W)    int32    gzip (only if present)
    /observations/cameras/<name>/intrinsics    (K, 3, 3)    float64
    /observations/cameras/<name>/extrinsics    (K, 4, 4)    float64  camera-to-world, OpenCV axes
    /actions/position          (K, 3) float64
    /actions/quaternion        (K, 4) float64  (x, y, z, w)
    /actions/gripper_open      (K,)   bool
    /actions/ignore_collision  (K,)   bool
    /actions/kind              (K,)   str    keyframe kind ("approach", "grasp", ...)
    /actions/symmetry          (K,)   int64  equivalent turns about the gripper axis (0 = any)
    /trajectory                 only for ``abm data generate --dense``: ``T`` frames at attrs["fps"]
    /trajectory/{gripper_open,gripper_pose,step,cameras/<name>/...}   as under /observations, per frame
    /trajectory/joint_positions (T, 9) float64  arm (7) + finger (2) joints
    /trajectory/joint_actions   (T, 8) float64  arm servo targets (7) + gripper command (1 = open)
    /trajectory/ee_actions      (T, 8) float64  next TCP position (3), quaternion (4) + gripper command
    /trajectory/keyframe_frames (K,)   int64    the frame each keyframe observation is

The trajectory group is optional (files without it are keyframe-only), so it did not change the version.

Every dataset carries a ``crc32`` attribute (CRC-32 of its values), and the root an ``attrs_crc32`` attribute
(JSON: the CRC-32 of every attribute of every object, the datasets' ``crc32`` aside, and of the names, types and
shapes of the datasets), that :func:`verify_episode`
and ``abm data info`` check; :func:`check_episodes` remembers which files passed and checks a file again whenever
its bytes may have changed. Readers check each attribute's type (a number where a number belongs), so a file
edited by hand is one error naming the file and the attribute.

Version 2 (labels are the orientation the arm reached, in the canonical member of their symmetry
class; see docs/benchmark.md) replaced version 1, whose grasp yaw labels could be the 180-degree flip
of what was executed. Version 1 files are refused with a message that says to regenerate them.

Besides the file format, each task's simulated objects and expert labels have a version
(:data:`abm.types.TASK_DATA_VERSIONS`: close_jar and water_plants are at 2, every other task at 1). An episode
recorded in simulation (its metadata names the ``mujoco`` version) stores the one it was made with as
``metadata["task_version"]`` (absent = 1); one of an older version than its task's current one is refused
like a version-1 file, with what changed and the command that regenerates it, while the other tasks'
episodes load unchanged. Episodes not recorded in simulation (a real robot's) are not versioned.

Writes are atomic (temporary file in the same folder, then :func:`os.replace`), so an interrupted run
never leaves a complete-looking partial file. Any unreadable, incomplete or wrong-version file raises
:class:`EpisodeFormatError` naming the file.
"""

from __future__ import annotations

import io
import json
import os
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from abm.errors import ConfigError, DataError
from abm.files import WriteError, sha256_file, write_error, write_text_atomic
from abm.types import (
    TASK_DATA_VERSIONS,
    TASK_VERSION_KEY,
    CameraFrame,
    Episode,
    KeyframeAction,
    Observation,
    Trajectory,
    task_data_version,
)

if TYPE_CHECKING:  # h5py is imported where files are read or written
    import h5py

FORMAT_VERSION: int = 2
EPISODE_SUFFIX = ".h5"
_COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


class EpisodeFormatError(DataError):
    """An episode file that cannot be read: the message names the file and the problem."""


@dataclass(frozen=True)
class EpisodeInfo:
    """Metadata of one stored episode (read without touching the image data)."""

    path: Path
    task: str
    split: str
    variation: int
    instruction: str
    num_keyframes: int
    success: bool
    seed: int
    cameras: str = ""
    """Camera signature, e.g. ``"front,left,right,wrist@128x128"``: episodes that differ here cannot
    be mixed in one dataset."""


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"metadata value of type {type(value).__name__} is not JSON-serialisable")


def save_episode(episode: Episode, path: str | os.PathLike[str]) -> None:
    """Write ``episode`` to ``path`` atomically (parents are created)."""
    import h5py

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise write_error(path, err) from None
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    steps = episode.steps
    camera_names = list(steps[0][0].cameras) if steps else []
    for k, (obs, _) in enumerate(steps):
        if list(obs.cameras) != camera_names:
            raise ValueError(f"keyframe {k} has cameras {list(obs.cameras)}, expected {camera_names}")
    buffer = io.BytesIO()  # built in memory, then written in one go: a full disk fails in Python, cleanly
    try:
        with h5py.File(buffer, "w") as f:
            attrs = f.attrs
            attrs["format_version"] = FORMAT_VERSION
            attrs["task"] = episode.task
            attrs["split"] = episode.split
            attrs["variation"] = int(episode.variation)
            attrs["instruction"] = episode.instruction
            attrs["success"] = bool(episode.success)
            attrs["seed"] = int(episode.seed)
            attrs["num_keyframes"] = len(steps)
            attrs["object_names"] = json.dumps({str(k): v for k, v in episode.object_names.items()})
            attrs["target_names"] = json.dumps(list(episode.target_names))
            attrs["camera_names"] = json.dumps(camera_names)
            attrs["metadata"] = json.dumps(episode.metadata, default=_json_default)
            obs_g = f.create_group("observations")
            obs_g["gripper_open"] = np.array([o.gripper_open for o, _ in steps], np.float32)
            obs_g["gripper_pose"] = np.array([o.gripper_pose for o, _ in steps], np.float64).reshape(-1, 4, 4)
            obs_g["step"] = np.array([o.step for o, _ in steps], np.int64)
            _write_cameras(obs_g.create_group("cameras"), [o for o, _ in steps], camera_names)
            act = f.create_group("actions")
            act["position"] = np.array([a.position for _, a in steps], np.float64).reshape(-1, 3)
            act["quaternion"] = np.array([a.quaternion for _, a in steps], np.float64).reshape(-1, 4)
            act["gripper_open"] = np.array([a.gripper_open for _, a in steps], bool)
            act["ignore_collision"] = np.array([a.ignore_collision for _, a in steps], bool)
            act.create_dataset("kind", data=[a.kind for _, a in steps], dtype=h5py.string_dtype())
            act["symmetry"] = np.array([a.symmetry for _, a in steps], np.int64)
            if episode.trajectory is not None:
                _write_trajectory(f.create_group("trajectory"), episode.trajectory, camera_names)
            f.visititems(_store_checksum)
            f.attrs[ATTRS_CHECKSUM] = json.dumps(_attribute_crcs(f), sort_keys=True)
        if tmp.is_symlink():  # a link planted at the temporary name would send the write elsewhere
            tmp.unlink()
        tmp.write_bytes(buffer.getbuffer())
        os.replace(tmp, path)
    except OSError as err:  # a full disk: one clear error, and the temporary file goes (finally)
        raise write_error(path, err) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def _write_cameras(cams: h5py.Group, observations: list[Observation], camera_names: list[str]) -> None:
    """``cams/<name>/{rgb,depth,segmentation,intrinsics,extrinsics}`` of a sequence of observations."""
    for name in camera_names:
        frames = [o.cameras[name] for o in observations]
        g = cams.create_group(name)
        h, w = frames[0].height, frames[0].width
        g.create_dataset("rgb", data=np.stack([c.rgb for c in frames]), chunks=(1, h, w, 3), **_COMPRESSION)
        g.create_dataset("depth", data=np.stack([c.depth for c in frames]).astype(np.float32),
                         chunks=(1, h, w), **_COMPRESSION)
        segmentations = [c.segmentation for c in frames if c.segmentation is not None]
        if len(segmentations) == len(frames):
            g.create_dataset("segmentation", data=np.stack(segmentations).astype(np.int32),
                             chunks=(1, h, w), **_COMPRESSION)
        g["intrinsics"] = np.stack([c.intrinsics for c in frames])
        g["extrinsics"] = np.stack([c.extrinsics for c in frames])


def _write_trajectory(g: h5py.Group, trajectory: Trajectory, camera_names: list[str]) -> None:
    """The optional ``/trajectory`` group of a ``--dense`` episode (same layout as ``/observations``, plus the
    joint state and the joint / end-effector actions of every control tick)."""
    obs = trajectory.observations
    g.attrs["fps"] = float(trajectory.fps)
    g["gripper_open"] = np.array([o.gripper_open for o in obs], np.float32)
    g["gripper_pose"] = np.array([o.gripper_pose for o in obs], np.float64)
    g["step"] = np.array([o.step for o in obs], np.int64)
    g["joint_positions"] = trajectory.joint_positions
    g["joint_actions"] = trajectory.joint_actions
    g["ee_actions"] = trajectory.ee_actions
    g["keyframe_frames"] = trajectory.keyframe_frames
    _write_cameras(g.create_group("cameras"), obs, camera_names)


def _read_observation(g: h5py.Group, k: int, camera_names: list[str]) -> Observation:
    """Observation ``k`` of a group written like ``/observations`` (or ``/trajectory``)."""
    cameras: dict[str, CameraFrame] = {}
    for name in camera_names:
        c = g["cameras"][name]
        cameras[name] = CameraFrame(rgb=c["rgb"][k], depth=c["depth"][k], intrinsics=c["intrinsics"][k],
                                    extrinsics=c["extrinsics"][k],
                                    segmentation=c["segmentation"][k] if "segmentation" in c else None)
    return Observation(cameras=cameras, gripper_open=float(g["gripper_open"][k]), gripper_pose=g["gripper_pose"][k],
                       step=int(g["step"][k]))


def _read_trajectory(f: h5py.File, path: Path, camera_names: list[str]) -> Trajectory | None:
    if "trajectory" not in f:
        return None
    g = f["trajectory"]
    try:
        n = len(g["step"])
        return Trajectory(fps=float(g.attrs["fps"]),
                          observations=[_read_observation(g, k, camera_names) for k in range(n)],
                          joint_positions=g["joint_positions"][()], joint_actions=g["joint_actions"][()],
                          ee_actions=g["ee_actions"][()], keyframe_frames=g["keyframe_frames"][()])
    except (KeyError, OSError, ValueError, IndexError, TypeError) as err:
        raise EpisodeFormatError(f"{path}: the dense trajectory cannot be read ({err})") from None


def _dataset_crc32(dataset: h5py.Dataset) -> int:
    """CRC-32 of a dataset's values (strings joined with NUL bytes)."""
    data = dataset[()]
    if data.dtype.kind == "O":
        payload = b"\0".join(x if isinstance(x, bytes) else str(x).encode() for x in data.ravel())
    else:
        payload = np.ascontiguousarray(data).tobytes()
    return zlib.crc32(payload)


def _store_checksum(name: str, obj: h5py.Group | h5py.Dataset) -> None:
    import h5py

    if isinstance(obj, h5py.Dataset):
        obj.attrs["crc32"] = _dataset_crc32(obj)


ATTRS_CHECKSUM = "attrs_crc32"


def _attribute_bytes(value: Any) -> bytes:
    """The bytes of an HDF5 attribute value as h5py reads it, its type included (a number that became text
    changes them)."""
    if isinstance(value, str):
        return b"s" + value.encode("utf-8", "surrogatepass")
    if isinstance(value, bytes):
        return b"b" + value
    array = np.asarray(value)
    if array.dtype.kind in "OSU":
        return b"o" + repr(array.shape).encode() + b"\0".join(
            x if isinstance(x, bytes) else str(x).encode("utf-8", "surrogatepass") for x in array.ravel())
    return b"n" + array.dtype.str.encode() + repr(array.shape).encode() + np.ascontiguousarray(array).tobytes()


LAYOUT_KEY = "(layout)"  # in the attribute checksums: the names, types and shapes of the groups and datasets


def _attribute_crcs(f: h5py.File) -> dict[str, int]:
    """CRC-32 of every attribute of every object of an open episode file (``name`` for the root's,
    ``object:name`` for the others'), except the checksums themselves, and of the file's layout
    (:data:`LAYOUT_KEY`: a dataset renamed, added or removed changes it)."""
    import h5py

    crcs = {key: zlib.crc32(_attribute_bytes(value)) for key, value in f.attrs.items() if key != ATTRS_CHECKSUM}
    layout: list[str] = []

    def visit(name: str, obj: h5py.Group | h5py.Dataset) -> None:
        is_dataset = isinstance(obj, h5py.Dataset)
        layout.append(f"{name} {obj.dtype.str} {obj.shape}" if is_dataset else f"{name}/")
        for key, value in obj.attrs.items():
            if not (key == "crc32" and is_dataset):
                crcs[f"{name}:{key}"] = zlib.crc32(_attribute_bytes(value))

    f.visititems(visit)
    crcs[LAYOUT_KEY] = zlib.crc32("\n".join(sorted(layout)).encode("utf-8", "surrogatepass"))
    return crcs


def _check_attributes(f: h5py.File, path: Path) -> bool:
    """Compare the attributes with the CRC-32s stored when the file was written; ``False`` for a file written
    before abm stored them."""
    stored_text = f.attrs.get(ATTRS_CHECKSUM)
    if stored_text is None:
        return False
    try:
        stored = json.loads(stored_text)
        stored = {str(k): int(v) for k, v in stored.items()}
    except (TypeError, ValueError, AttributeError):
        raise EpisodeFormatError(f"{path}: its attribute checksums ({ATTRS_CHECKSUM!r}) cannot be read; the file "
                                 f"is corrupt {_REGENERATE}") from None
    now = _attribute_crcs(f)
    changed = sorted(k if k != LAYOUT_KEY else "the names, types or shapes of its datasets"
                     for k in stored.keys() & now.keys() if stored[k] != now[k])
    added, removed = sorted(now.keys() - stored.keys()), sorted(stored.keys() - now.keys())
    if changed or added or removed:
        what = "; ".join(part for part in (
            f"changed: {', '.join(changed)}" if changed else "", f"added: {', '.join(added)}" if added else "",
            f"removed: {', '.join(removed)}" if removed else "") if part)
        raise EpisodeFormatError(f"{path}: attributes do not match their checksums ({what}); the file was changed "
                                 f"after it was written {_REGENERATE}")
    return True


_REGENERATE = "(delete it and run `abm data generate` again to replace it, or import it again)"


def verify_episode(path: str | os.PathLike[str]) -> bool:
    """Read every dataset of an episode file and compare it with the CRC-32 stored when it was written.

    The attributes (task, split, seed, instruction, metadata, ...) are compared with their CRC-32s too.

    Returns:
        ``True`` if every dataset and attribute was checked, ``False`` if the file lacks some checksums (written
        by an older abm) but everything could be read.

    Raises:
        EpisodeFormatError: a dataset cannot be read, or a dataset or attribute does not match its checksum.
    """
    import h5py

    path = Path(path)
    missing = 0
    f = _open(path)
    with f:
        names: list[str] = []
        name = "/"
        try:
            f.visititems(lambda n, obj: names.append(n) if isinstance(obj, h5py.Dataset) else None)
            for name in names:
                ds = f[name]
                crc = _dataset_crc32(ds)
                stored = ds.attrs.get("crc32")
                if stored is None:
                    missing += 1
                elif int(stored) != crc:
                    raise EpisodeFormatError(f"{path}: dataset {name} does not match its checksum; the file is "
                                             "corrupt (delete it and run `abm data generate` again to replace it)")
        except EpisodeFormatError:
            raise
        except Exception as err:  # noqa: BLE001 - h5py/zlib raise many types for damaged data
            raise EpisodeFormatError(f"{path}: dataset {name} cannot be read ({err}); the file is corrupt") from None
        try:
            attributes_checked = _check_attributes(f, path)
        except EpisodeFormatError:
            raise
        except Exception as err:  # noqa: BLE001 - h5py raises many types for damaged attributes
            raise EpisodeFormatError(f"{path}: its attributes cannot be read ({err}); the file is corrupt "
                                     f"{_REGENERATE}") from None
    return missing == 0 and attributes_checked


VERIFIED_RECORD = ".abm_verified.json"
#: up to this many bytes of episodes, :func:`check_episodes` reads every file that passed before again (sha256 of
#: its bytes, ~1 GB/s) rather than trusting its size and times
FULL_CHECK_BYTES = 1 << 30


def _stamp(stat: os.stat_result) -> list[int]:
    """What changes when a file's bytes may have: its size, modification and status-change times, and inode.
    The status-change time cannot be set back (``touch -d`` / ``os.utime`` set it to now), so an edit that
    keeps the size and puts the modification time back still changes the stamp."""
    return [stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns, stat.st_ino]


def check_episodes(paths: Sequence[str | os.PathLike[str]], root: str | os.PathLike[str] | None = None
                   ) -> list[tuple[Path, str]]:
    """Verify the checksums of episode files (:func:`verify_episode`); ``(path, reason)`` of each bad one.

    A file that passed is remembered in ``ROOT/.abm_verified.json`` with its size, times, inode and the sha256 of
    its bytes. It is verified again when any of them changed: while the files checked total at most
    :data:`FULL_CHECK_BYTES`, every file's bytes are hashed again (an edit that keeps the size and times is
    found); above that, the stamp (:func:`_stamp`, whose status-change time no edit can keep) decides.
    """
    record_path = Path(root) / VERIFIED_RECORD if root is not None else None
    try:
        record = json.loads(record_path.read_text()) if record_path is not None and record_path.is_file() else {}
        record = record if isinstance(record, dict) else {}
    except (OSError, ValueError):
        record = {}
    files = [Path(p) for p in paths]
    try:
        full = sum(p.stat().st_size for p in files) <= FULL_CHECK_BYTES
    except OSError:
        full = True
    bad: list[tuple[Path, str]] = []
    changed = False
    for p in files:
        key = str(p.relative_to(root)) if root is not None and p.is_relative_to(root) else str(p)
        entry = record.get(key)
        try:
            stamp = _stamp(p.stat())
            if isinstance(entry, dict) and entry.get("stamp") == stamp:
                if not full:
                    continue
                digest = sha256_file(p)
                if digest == entry.get("sha256"):
                    continue
            else:
                digest = sha256_file(p)
            verify_episode(p)
            if _stamp(p.stat()) != stamp:  # written while it was checked: check it next time
                record.pop(key, None)
                changed = True
                continue
        except (OSError, EpisodeFormatError) as err:
            changed |= record.pop(key, None) is not None
            bad.append((p, str(err)))
            continue
        record[key] = {"stamp": stamp, "sha256": digest}
        changed = True
    if record_path is not None and changed:
        try:
            write_text_atomic(record_path, json.dumps(record, indent=0, sort_keys=True))
        except WriteError:
            pass  # a read-only store is checked again next time
    return bad


def _open(path: Path) -> h5py.File:
    import h5py

    if not path.is_file():
        raise ConfigError(f"episode file not found: {path}")
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise EpisodeFormatError(f"{path}: not a readable HDF5 episode file ({err})") from None
    try:
        version = f.attrs.get("format_version")
        if version is None:
            raise EpisodeFormatError(f"{path}: missing 'format_version' attribute (not an abm episode file)")
        version = _typed(path, "format_version", version, "integer")
    except BaseException:
        f.close()
        raise
    if version != FORMAT_VERSION:
        f.close()
        hint = (" Version 1 demonstrations have inconsistent gripper-yaw labels; regenerate them with "
                "`abm data generate` (same arguments, into a new folder)." if version < FORMAT_VERSION
                else " Upgrade abm to read it.")
        raise EpisodeFormatError(f"{path}: episode format version {version} is not supported "
                                 f"(this abm reads version {FORMAT_VERSION}).{hint}")
    problem = _task_version_problem(f)
    if problem is not None:
        f.close()
        raise EpisodeFormatError(f"{path}: {problem}")
    return f


def outdated_task_version(task: str, metadata: object) -> str | None:
    """Why an episode of ``task`` with this ``metadata`` must be regenerated, or ``None`` if it may be used.

    Only episodes recorded in simulation (metadata with a ``"mujoco"`` entry) are versioned: one whose
    ``metadata["task_version"]`` (absent = 1) is older than :func:`abm.types.task_data_version` shows other
    objects or teaches other labels than the task now has.
    """
    if not isinstance(metadata, dict) or "mujoco" not in metadata:
        return None
    want = task_data_version(task)
    try:
        have = int(metadata.get(TASK_VERSION_KEY, 1))
    except (TypeError, ValueError):
        return f"its {TASK_VERSION_KEY!r} metadata entry {metadata.get(TASK_VERSION_KEY)!r} is not a version number"
    if have >= want:
        return None
    change = TASK_DATA_VERSIONS[task][1]
    return (f"this {task} episode was recorded with version {have} of the task's objects and labels, but the "
            f"{task} task is now version {want} ({change}), so the episode no longer matches the task. "
            f"Regenerate it with `abm data generate --task {task}` (same arguments, into a new folder).")


def _task_version_problem(f: h5py.File) -> str | None:
    """:func:`outdated_task_version` of an open file (``None`` if its task or metadata cannot be read: the
    readers report those themselves)."""
    try:
        task, metadata = str(f.attrs["task"]), json.loads(f.attrs["metadata"])
    except (KeyError, TypeError, ValueError):
        return None
    return outdated_task_version(task, metadata)


def _attr(f: h5py.File, path: Path, key: str) -> Any:  # an HDF5 attribute: str, number or array
    try:
        return f.attrs[key]
    except KeyError:
        raise EpisodeFormatError(f"{path}: missing attribute {key!r}") from None
    except Exception as err:  # noqa: BLE001 - h5py raises many types for a damaged attribute
        raise EpisodeFormatError(f"{path}: attribute {key!r} cannot be read ({err}); the file is corrupt "
                                 f"{_REGENERATE}") from None


_EXPECTED = {"integer": "a whole number", "text": "text", "flag": "true or false (a boolean)"}


def _typed(path: Path, key: str, value: Any, kind: str) -> Any:
    """An attribute value as ``kind`` (``integer``, ``text``, ``flag``), or :class:`EpisodeFormatError` naming
    the file, the attribute, what it holds and what it should."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if kind == "integer" and isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_):
        return int(value)
    if kind == "text" and isinstance(value, str):
        return str(value)
    if kind == "text" and isinstance(value, bytes):
        try:
            return value.decode("utf-8")
        except UnicodeDecodeError:
            pass
    if kind == "flag" and (isinstance(value, bool | np.bool_) or (isinstance(value, int | np.integer)
                                                                   and int(value) in (0, 1))):
        return bool(value)
    shown = repr(value.tolist() if isinstance(value, np.ndarray | np.generic) else value)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    raise EpisodeFormatError(f"{path}: attribute {key!r} is {shown} ({_type_name(value)}), expected "
                             f"{_EXPECTED[kind]}; the file was damaged or edited after it was written {_REGENERATE}")


def _type_name(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    if isinstance(value, str | bytes):
        return "text"
    if isinstance(value, bool | np.bool_):
        return "a boolean"
    if isinstance(value, int | np.integer):
        return "a whole number"
    if isinstance(value, float | np.floating):
        return "a real number"
    return type(value).__name__


def _info(f: h5py.File, path: Path) -> EpisodeInfo:
    def get(key: str, kind: str) -> Any:
        return _typed(path, key, _attr(f, path, key), kind)

    return EpisodeInfo(path=path, task=get("task", "text"), split=get("split", "text"),
                       variation=get("variation", "integer"), instruction=get("instruction", "text"),
                       num_keyframes=get("num_keyframes", "integer"), success=get("success", "flag"),
                       seed=get("seed", "integer"), cameras=_camera_signature(f, path))


def _camera_signature(f: h5py.File, path: Path) -> str:
    names = list(_json_attr(f, path, "camera_names"))
    try:
        shape = f["observations"]["cameras"][names[0]]["depth"].shape[1:] if names else ()
    except KeyError as err:
        raise EpisodeFormatError(f"{path}: camera data missing ({err})") from None
    return ",".join(names) + "@" + "x".join(str(int(n)) for n in shape)


def load_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The free-form metadata of one episode file (no image data is read)."""
    path = Path(path)
    f = _open(path)
    with f:
        metadata: dict[str, Any] = _json_attr(f, path, "metadata")
        return metadata


def read_info(path: str | os.PathLike[str]) -> EpisodeInfo:
    """Metadata of one episode file (no image data is read)."""
    path = Path(path)
    f = _open(path)
    with f:
        return _info(f, path)


def _read_step(f: h5py.File, path: Path, k: int, camera_names: list[str]) -> tuple[Observation, KeyframeAction]:
    try:
        act = f["actions"]
        obs = _read_observation(f["observations"], k, camera_names)
        action = KeyframeAction(position=act["position"][k], quaternion=act["quaternion"][k],
                                gripper_open=bool(act["gripper_open"][k]),
                                ignore_collision=bool(act["ignore_collision"][k]),
                                kind=act["kind"].asstr()[k], symmetry=int(act["symmetry"][k]))
    except (KeyError, OSError, ValueError, IndexError) as err:
        raise EpisodeFormatError(f"{path}: keyframe {k} cannot be read ({err})") from None
    return obs, action


#: what each JSON attribute holds: a mapping or a list, and the type of its values
_JSON_ATTRS: dict[str, tuple[type, str]] = {
    "object_names": (dict, "a JSON object of object ids (whole numbers) to names"),
    "target_names": (list, "a JSON list of names"), "camera_names": (list, "a JSON list of camera names"),
    "metadata": (dict, "a JSON object"),
}


def _json_attr(f: h5py.File, path: Path, key: str) -> Any:  # parsed JSON, of the type _JSON_ATTRS says
    text = _typed(path, key, _attr(f, path, key), "text")
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise EpisodeFormatError(f"{path}: attribute {key!r} is not valid JSON ({err}); the file was damaged or "
                                 f"edited after it was written {_REGENERATE}") from None
    kind, expected = _JSON_ATTRS.get(key, (object, "JSON"))
    good = isinstance(value, kind)
    if good and key == "object_names":
        good = all(isinstance(v, str) and k.strip().lstrip("-").isdigit() for k, v in value.items())
    elif good and kind is list:
        good = all(isinstance(v, str) for v in value)
    if not good:
        shown = text if len(text) <= 60 else text[:57] + "..."
        raise EpisodeFormatError(f"{path}: attribute {key!r} is {shown}, expected {expected}; the file was damaged "
                                 f"or edited after it was written {_REGENERATE}")
    return value


def load_episode(path: str | os.PathLike[str]) -> Episode:
    """Read a whole episode written by :func:`save_episode`."""
    path = Path(path)
    f = _open(path)
    with f:
        info = _info(f, path)
        camera_names = _json_attr(f, path, "camera_names")
        steps = [_read_step(f, path, k, camera_names) for k in range(info.num_keyframes)]
        object_names = {int(k): v for k, v in _json_attr(f, path, "object_names").items()}
        target_names, metadata = list(_json_attr(f, path, "target_names")), _json_attr(f, path, "metadata")
        trajectory = _read_trajectory(f, path, camera_names)
        try:
            return Episode(task=info.task, variation=info.variation, split=info.split,
                           instruction=info.instruction, object_names=object_names, target_names=target_names,
                           steps=steps, success=info.success, seed=info.seed, metadata=metadata,
                           trajectory=trajectory)
        except ValueError as err:
            raise EpisodeFormatError(f"{path}: invalid episode ({err})") from None


def find_episode_files(root: str | os.PathLike[str]) -> list[Path]:
    """Episode files under ``root`` (recursively, sorted; temporary files are skipped)."""
    root = Path(root)
    if not root.is_dir():
        raise ConfigError(f"episode directory not found: {root}")
    return sorted(p for p in root.rglob(f"*{EPISODE_SUFFIX}") if p.is_file() and not p.name.startswith("."))


IMPORT_MARKER = ".import-incomplete"
"""Left in an episode folder while ``abm data import`` writes into it (and after it failed or was stopped):
its first line is the command that finishes the import."""


class IncompleteStoreError(EpisodeFormatError):
    """An episode folder whose import did not finish (it holds :data:`IMPORT_MARKER`)."""


def check_complete(root: str | os.PathLike[str]) -> None:
    """Raise :class:`IncompleteStoreError` if an ``abm data import`` into ``root`` (or into a folder above or
    below it) did not finish: such a folder holds only part of the dataset, so nothing may use it as a store."""
    root = Path(root)
    markers = [d / IMPORT_MARKER for d in (root, *root.resolve().parents) if (d / IMPORT_MARKER).is_file()]
    markers += sorted(root.rglob(IMPORT_MARKER)) if not markers and root.is_dir() else []
    if not markers:
        return
    marker = markers[0]
    try:
        command = marker.read_text(encoding="utf-8").splitlines()[0].strip()
    except (OSError, UnicodeDecodeError, IndexError):
        command = ""
    finish = f"run `{command}` again to finish it" if command.startswith("abm ") else "run the import again"
    raise IncompleteStoreError(
        f"{marker.parent}: an abm data import into this folder did not finish ({marker} is there), so it holds "
        f"only part of the dataset; {finish} (with --overwrite, which replaces the episodes it already wrote), "
        "or delete the folder and import again")


def held_out_overlap(data: str | os.PathLike[str], val_data: str | os.PathLike[str]) -> str | None:
    """Why ``val_data`` is not held out from ``data`` (``None`` when it is): the same folder, one inside the
    other, the same episode files (links included), or episodes of the same scenes (the same
    ``task/split/episode_<seed>.h5`` under both)."""
    train_root, val_root = Path(data).resolve(), Path(val_data).resolve()
    if train_root == val_root:
        return f"--val-data {val_data} is the same folder as --data {data}"
    if val_root.is_relative_to(train_root):
        return f"--val-data {val_data} is inside --data {data}, so its episodes are training episodes"
    if train_root.is_relative_to(val_root):
        return f"--data {data} is inside --val-data {val_data}, so the training episodes are validation episodes"
    if not train_root.is_dir() or not val_root.is_dir():
        return None
    train_files = find_episode_files(train_root)
    identities = {}
    for p in train_files:
        stat = p.stat()
        identities[(stat.st_dev, stat.st_ino)] = p
    names = {p.relative_to(train_root) for p in train_files}
    for p in find_episode_files(val_root):
        stat = p.stat()
        same = identities.get((stat.st_dev, stat.st_ino))
        if same is not None:
            return f"--val-data {val_data} holds the same episode files as --data {data} (e.g. {p} is {same})"
        if p.relative_to(val_root) in names:
            return (f"--val-data {val_data} holds episodes of the same scenes as --data {data} (e.g. "
                    f"{p.relative_to(val_root)} in both)")
    return None


class EpisodeStore:
    """All episodes under a directory, indexed by their metadata.

    Args:
        root: directory scanned recursively for ``*.h5`` episode files.

    Raises:
        IncompleteStoreError: an ``abm data import`` into ``root`` did not finish (:func:`check_complete`).
    """

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)
        if self.root.is_dir():
            check_complete(self.root)
        self.episodes: list[EpisodeInfo] = [read_info(p) for p in find_episode_files(self.root)]

    def __len__(self) -> int:
        return len(self.episodes)

    def _info(self, i: int) -> EpisodeInfo:
        if not 0 <= i < len(self.episodes):
            raise IndexError(f"episode index {i} out of range (store has {len(self.episodes)} episodes)")
        return self.episodes[i]

    def load(self, i: int) -> Episode:
        """The whole episode ``i``."""
        return load_episode(self._info(i).path)

    def load_step(self, i: int, k: int) -> tuple[Observation, KeyframeAction]:
        """Only keyframe ``k`` of episode ``i`` (reads one chunk per camera array)."""
        info = self._info(i)
        if not 0 <= k < info.num_keyframes:
            raise IndexError(f"keyframe {k} out of range ({info.path} has {info.num_keyframes} keyframes)")
        f = _open(info.path)
        with f:
            return _read_step(f, info.path, k, _json_attr(f, info.path, "camera_names"))

    def load_positions(self, i: int) -> NDArray[np.float64]:
        """``(K, 3)`` keyframe target positions (m) of episode ``i``, without reading any image."""
        info = self._info(i)
        f = _open(info.path)
        with f:
            try:
                return np.asarray(f["actions"]["position"][:], np.float64).reshape(-1, 3)
            except (KeyError, OSError, ValueError) as err:
                raise EpisodeFormatError(f"{info.path}: keyframe positions cannot be read ({err})") from None

    def select(self, tasks: Iterable[str] | None = None, splits: Iterable[str] | None = None) -> list[int]:
        """Indices of the episodes whose task and split are among the given ones (``None`` = any)."""
        tasks = set(tasks) if tasks is not None else None
        splits = set(splits) if splits is not None else None
        return [i for i, e in enumerate(self.episodes)
                if (tasks is None or e.task in tasks) and (splits is None or e.split in splits)]

    def nothing_selected(self, tasks: Iterable[str] | None = None, splits: Iterable[str] | None = None) -> str:
        """The message for a :meth:`select` that found nothing: what was asked for, what the store holds, the fix."""
        asked = [f"task {', '.join(tasks)}" if tasks else "", f"split {', '.join(splits)}" if splits else ""]
        wanted = " and ".join(a for a in asked if a)
        if not self.episodes:
            return (f"no episodes in {self.root} (no *{EPISODE_SUFFIX} episode files in it or its folders): give the "
                    "folder abm data generate or abm data import wrote")
        held: dict[str, int] = {}
        for e in self.episodes:
            held[f"{e.task}/{e.split}"] = held.get(f"{e.task}/{e.split}", 0) + 1
        listing = ", ".join(f"{k} ({n})" for k, n in sorted(held.items()))
        return (f"no episodes of {wanted or 'any task'} in {self.root}; it holds {listing}: choose among those "
                "(--tasks / --splits), or generate the missing ones with abm data generate")

    def check_consistent(self, indices: Iterable[int]) -> None:
        """Raise :class:`EpisodeFormatError` if the episodes were recorded with different cameras."""
        seen: dict[str, Path] = {}
        for i in indices:
            info = self._info(i)
            seen.setdefault(info.cameras, info.path)
        if len(seen) > 1:
            listing = "; ".join(f"{sig} (e.g. {p})" for sig, p in seen.items())
            raise EpisodeFormatError(f"{self.root} mixes episodes recorded with different cameras: {listing}. "
                                     "Keep each camera setup in its own folder.")
