"""Policy checkpoints: atomic saving, finding the latest one in a run, loading with clear errors.

A checkpoint is a ``torch.save`` dict::

    format: "abm-policy", version: 1,
    policy_config: PolicyConfig.to_dict(), variant: str, preset: str,
    language: encoder spec, grounder: grounder spec, camera_names: list | None,
    model: state_dict, step: int,
    # training state (absent from exported inference checkpoints)
    optimizer, scheduler, rng: {torch, numpy, python, cuda}, train_config: dict

Runs keep them as ``RUN/checkpoints/step_00001000.pt``. Loading uses ``torch.load(weights_only=True)``:
tensors and plain data only, so a crafted file is refused instead of running its code.

Every checkpoint is checked byte for byte before it is loaded: the files abm writes carry the sha256 of their
bytes (:func:`abm.files.seal_torch_archive`), a file listed in a model zoo index next to it (``index.json``)
must match the sha256 the index records, and any other zip checkpoint the CRC-32 of each of its members
(:func:`abm.files.check_torch_archive`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from abm.errors import CheckpointError, DataError, OutputError
from abm.files import atomic_path, is_inside, load_torch_data, seal_torch_archive, sha256_file

try:
    from numpy._core.multiarray import _reconstruct
except ImportError:  # numpy < 2
    from numpy.core.multiarray import _reconstruct  # type: ignore[no-redef]  # same function, numpy 1 path

_NUMPY_ARRAY_GLOBALS = [_reconstruct, np.ndarray, np.dtype, type(np.dtype(np.uint32))]

FORMAT = "abm-policy"
VERSION = 1
_STEP_FILE = re.compile(r"step_(\d+)\.pt$")


def checkpoint_dir(run_dir: str | Path) -> Path:
    return Path(run_dir) / "checkpoints"


def checkpoint_path(run_dir: str | Path, step: int) -> Path:
    return checkpoint_dir(run_dir) / f"step_{step:08d}.pt"


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write atomically (temporary file + rename), so an interruption never leaves a broken checkpoint; the file
    records the sha256 of its bytes (:func:`abm.files.seal_torch_archive`), which every load checks."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with tmp.open("wb") as fh:  # Python file: a full disk raises OSError
            torch.save({"format": FORMAT, "version": VERSION, **payload}, fh)
        seal_torch_archive(tmp)
    return path


def list_checkpoints(run_dir: str | Path) -> list[tuple[int, Path]]:
    """``(step, path)`` of a run's checkpoints, oldest first."""
    folder = checkpoint_dir(run_dir)
    if not folder.is_dir():
        return []
    found = []
    for p in folder.iterdir():
        m = _STEP_FILE.search(p.name)
        if m:
            found.append((int(m.group(1)), p))
    return sorted(found)


def resolve_checkpoint(run_or_ckpt: str | Path) -> Path:
    """A checkpoint file itself, or the latest checkpoint of a run folder."""
    p = Path(run_or_ckpt)
    if p.is_file():
        return p
    if p.is_dir():
        ckpts = list_checkpoints(p)
        if not ckpts:
            raise CheckpointError(f"no checkpoint in {checkpoint_dir(p)} (expected step_XXXXXXXX.pt files)")
        return ckpts[-1][1]
    raise CheckpointError(f"no checkpoint or run folder at {p}")


def load_checkpoint(run_or_ckpt: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load and sanity-check a checkpoint (file or run folder)."""
    path = resolve_checkpoint(run_or_ckpt)
    check_zoo_sha256(path)
    # weights_only: tensors and plain data only, so a crafted file cannot run code. Checkpoints
    # written before the numpy RNG state was stored as a tensor also hold numpy arrays.
    data = load_torch_data(path, "abm checkpoint", _NUMPY_ARRAY_GLOBALS, map_location)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not an abm policy checkpoint")
    if int(data.get("version", 0)) > VERSION:
        raise CheckpointError(f"{path} has checkpoint version {data['version']}; this abm reads up to {VERSION}")
    data["path"] = str(path)
    return data


ZOO_INDEX = "index.json"


def check_zoo_sha256(path: str | Path) -> None:
    """Refuse a model file whose folder's zoo index (``index.json``, :mod:`abm.zoo`) lists it with another
    sha256, so a zoo model is checked byte for byte however it is loaded (``abm eval --run models/X.pt`` too).
    A folder without an index, or an index that does not list the file, checks nothing here."""
    path = Path(path)
    index = path.parent / ZOO_INDEX
    if not index.is_file():
        return
    try:
        entries = json.loads(index.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise DataError(f"{index} (the model zoo index next to {path.name}) cannot be read ({err}); restore it "
                        "with git checkout, or rewrite it with abm experiment run paper_tables") from None
    for entry in entries if isinstance(entries, list) else []:
        if not isinstance(entry, dict):
            continue
        file = entry.get("file", entry.get("name"))
        if not isinstance(file, str) or not file or Path(file).is_absolute() or not is_inside(index.parent / file,
                                                                                               index.parent):
            continue
        if (index.parent / file).resolve() != path.resolve():
            continue
        if not isinstance(entry.get("sha256"), str) or sha256_file(path) != entry["sha256"]:
            raise CheckpointError(f"{path} does not match the sha256 that {index} records for it (a changed byte, a "
                                  "partial download or another file): restore it with git checkout, or re-export it")
        return


TRAINING_STATE_KEYS = ("optimizer", "scheduler", "rng")


def export_checkpoint(run_or_ckpt: str | Path, out: str | Path, dtype: torch.dtype | None = None,
                      records: Mapping[str, Any] | None = None) -> Path:
    """Write an inference checkpoint: the weights and what loading needs, without the training state.

    The optimizer's moments are about twice the weights, so this is ~3x smaller; ``dtype`` (e.g.
    ``torch.bfloat16``) halves it again by casting the floating-point weights. Loading casts them back to
    the model's dtype, so an exported file is used exactly like a training checkpoint
    (``abm eval --run FILE``, ``KeyframePolicy.from_checkpoint``). ``records`` are added to the file (e.g. the
    experiment carry's ``slimmed_from_sha256``).
    """
    data = load_checkpoint(run_or_ckpt)
    payload = {k: v for k, v in data.items() if k not in (*TRAINING_STATE_KEYS, "path", "format", "version")}
    payload |= dict(records or {})
    if dtype is not None:
        for key in ("model", "zoom_model"):  # the network, and the zoomed stage's of a two-stage policy
            if key in data:
                payload[key] = {k: v.to(dtype) if v.is_floating_point() else v for k, v in data[key].items()}
        payload["exported_dtype"] = str(dtype).removeprefix("torch.")
    return save_checkpoint(out, payload)


def check_export_target(source: str | Path, out: str | Path, overwrite: bool = False) -> None:
    """Refuse an export path that would lose data: the exported checkpoint itself, a file inside a run's
    ``checkpoints`` folder (where resuming looks), an existing folder, or an existing file (unless
    ``overwrite``)."""
    out = Path(out)
    parent = next((p for p in out.parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise OutputError(f"--out {out}: {parent} is a file, not a folder; choose another path")
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give a file path such as {out / 'policy.pt'}")
    if out.exists() and out.resolve() == Path(source).resolve():
        raise OutputError(f"--out {out} is the checkpoint being exported; write the export to another file")
    if out.resolve().parent.name == checkpoint_dir("").name:
        raise OutputError(f"--out {out} is inside a run's checkpoints folder, where abm train and --resume look "
                          "for the newest checkpoint; write the export outside it (e.g. next to the run)")
    if out.exists() and not overwrite:
        raise OutputError(f"--out {out} already exists; pass --overwrite to replace it, or choose another path")


def prune_checkpoints(run_dir: str | Path, keep: int) -> None:
    """Delete all but the ``keep`` newest checkpoints (``keep <= 0`` keeps all)."""
    if keep <= 0:
        return
    for _, p in list_checkpoints(run_dir)[:-keep]:
        p.unlink(missing_ok=True)
