"""Cache of frozen grounding results: an in-memory LRU in front of an optional on-disk store.

Keys are SHA-1 hex digests of everything a result depends on (frame content, model, prompt,
settings; see :func:`content_key`). On disk each entry is ``DIR/<key[:2]>/<key>.npz`` holding named
arrays, written atomically (temporary file + rename) so an interrupted run never leaves a corrupt
entry; unreadable entries are treated as misses and rewritten.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from abm.geometry import PointCloud
from abm.types import CameraFrame


def _update(h: hashlib._Hash, part: object) -> None:
    if isinstance(part, np.ndarray):
        arr = np.ascontiguousarray(part)
        h.update(f"{arr.dtype.str}{arr.shape}".encode())
        h.update(arr.tobytes())
    elif isinstance(part, bytes):
        h.update(part)
    else:
        h.update(repr(part).encode())
    h.update(b"\x00")


def content_key(*parts: object) -> str:
    """SHA-1 hex digest of the parts (arrays hashed by dtype, shape and bytes; others by ``repr``)."""
    h = hashlib.sha1()
    for part in parts:
        _update(h, part)
    return h.hexdigest()


def image_key(rgb: np.ndarray) -> str:
    """Digest of one image's pixels."""
    return content_key(np.asarray(rgb))


def frame_key(frame: CameraFrame) -> str:
    """Digest of one camera frame: pixels, depth and calibration."""
    return content_key(frame.rgb, np.asarray(frame.depth), frame.intrinsics, frame.extrinsics)


def cloud_key(cloud: PointCloud) -> str:
    """Digest of a point cloud's geometry and provenance (which camera pixel each point came from)."""
    return content_key(cloud.xyz, cloud.camera_index, cloud.pixels, tuple(cloud.camera_names))


class GroundingCache:
    """LRU memory cache (``memory_items`` entries) optionally backed by a folder of ``.npz`` files.

    Args:
        directory: where entries are stored; ``None`` = memory only.
        memory_items: how many entries the in-memory LRU keeps.

    Attributes:
        hits, misses: lookup counters (memory or disk hit / neither).
    """

    def __init__(self, directory: str | Path | None = None, memory_items: int = 512) -> None:
        self.directory = Path(directory) if directory is not None else None
        if self.directory is not None:
            self.directory.mkdir(parents=True, exist_ok=True)
        self.memory_items = int(memory_items)
        self._memory: OrderedDict[str, dict[str, np.ndarray]] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def _path(self, key: str) -> Path:
        assert self.directory is not None
        return self.directory / key[:2] / f"{key}.npz"

    def _remember(self, key: str, value: dict[str, np.ndarray]) -> None:
        if self.memory_items <= 0:
            return
        self._memory[key] = value
        self._memory.move_to_end(key)
        while len(self._memory) > self.memory_items:
            self._memory.popitem(last=False)

    def get(self, key: str) -> dict[str, np.ndarray] | None:
        """The arrays stored under ``key``, or None."""
        if key in self._memory:
            self._memory.move_to_end(key)
            self.hits += 1
            return self._memory[key]
        if self.directory is not None:
            path = self._path(key)
            if path.is_file():
                try:
                    with np.load(path, allow_pickle=False) as data:
                        value = {k: data[k] for k in data.files}
                except (OSError, ValueError, EOFError):
                    value = None
                if value is not None:
                    self._remember(key, value)
                    self.hits += 1
                    return value
        self.misses += 1
        return None

    def put(self, key: str, value: Mapping[str, np.ndarray]) -> None:
        """Store named arrays under ``key`` (memory, and disk when a directory is set)."""
        value = {k: np.asarray(v) for k, v in value.items()}
        self._remember(key, value)
        if self.directory is None:
            return
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        np.savez(buffer, **value)  # type: ignore[arg-type]  # numpy types **kwds as able to fill allow_pickle
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(buffer.getvalue())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def __contains__(self, key: str) -> bool:
        return key in self._memory or (self.directory is not None and self._path(key).is_file())
