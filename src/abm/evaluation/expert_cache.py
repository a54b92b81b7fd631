"""The scripted expert's keyframes per scene, kept on disk across evaluations.

Every outcome's step records name the expert keyframe nearest to each prediction
(:func:`abm.evaluation.step_records.expert_keyframes`), and ``--expert-keyframes move`` needs them before the
rollout. Running the expert costs about a second per scene, and a table edition evaluates every scene once per
model and repeat, each evaluation in its own processes. The keyframes depend only on the scene (task, split, seed,
split file) and on the code that builds and executes it, so they are computed once and read back afterwards.

A file is keyed by all of that: ``FOLDER/TASK/SPLIT/SEED-SPLITS-CODE.json`` with ``SPLITS`` a digest of the split
file's bytes (``builtin`` without one) and ``CODE`` :func:`abm.evaluation.policies.code_digest`, so any change of
the package's source computes them anew. Floats are written by ``json`` in their shortest exact form: a keyframe
read back is bit for bit the one computed, and outcomes are the same with or without the cache.

The folder is ``$ABM_EXPERT_CACHE`` (``off`` switches the cache off), else ``~/.cache/abm/expert-keyframes``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from abm.types import KeyframeAction

#: environment variable naming the cache folder (``off``: no disk cache)
ENV = "ABM_EXPERT_CACHE"
DEFAULT_FOLDER = "~/.cache/abm/expert-keyframes"


def cache_folder() -> Path | None:
    """The cache folder (module doc), or ``None`` when the cache is off."""
    value = os.environ.get(ENV, DEFAULT_FOLDER)
    if value.strip().lower() in ("off", "0", "none", ""):
        return None
    return Path(value).expanduser()


def scene_file(folder: Path, task: str, split: str, seed: int, splits_path: str | None, code: str) -> Path:
    """The file of one scene's expert keyframes under ``folder`` (module doc)."""
    splits = "builtin" if splits_path is None else hashlib.sha256(Path(splits_path).read_bytes()).hexdigest()[:12]
    return folder / task / split / f"{seed}-{splits}-{code}.json"


def to_json(keyframes: Sequence[KeyframeAction]) -> list[dict[str, Any]]:
    """The keyframes as JSON-ready dicts (positions in metres, quaternions ``(x, y, z, w)``)."""
    return [{"position": k.position.tolist(), "quaternion": k.quaternion.tolist(), "gripper_open": k.gripper_open,
             "ignore_collision": k.ignore_collision, "kind": k.kind, "symmetry": k.symmetry} for k in keyframes]


def from_json(rows: Sequence[dict[str, Any]]) -> tuple[KeyframeAction, ...]:
    """Keyframes from :func:`to_json`'s rows, bit for bit (the stored quaternion is already normalised: it is put
    back as stored, not normalised a second time, which could move its last bit)."""
    keyframes = []
    for row in rows:
        keyframe = KeyframeAction(**row)
        keyframe.quaternion = np.asarray(row["quaternion"], np.float64)
        keyframes.append(keyframe)
    return tuple(keyframes)


def read(path: Path) -> tuple[KeyframeAction, ...] | None:
    """The keyframes stored at ``path``, or ``None`` when there is no readable file (a damaged one is ignored and
    computed anew)."""
    try:
        return from_json(json.loads(path.read_text()))
    except (OSError, ValueError, TypeError, KeyError):
        return None


def write(path: Path, keyframes: Sequence[KeyframeAction]) -> None:
    """Store ``keyframes`` at ``path`` atomically (a concurrent reader sees the whole file or none); a folder that
    cannot be written is skipped silently (the cache only saves time)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor, name = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(descriptor, "w") as handle:
            json.dump(to_json(keyframes), handle)
        os.replace(name, path)
    except OSError:
        Path(name).unlink(missing_ok=True)
