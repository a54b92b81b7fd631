"""The committed model zoo (``models/``): its index (``models/index.json``, written by the report of
``abm experiment run paper_tables``), the sha256 checks of its files and the choice of the entries
``abm zoo eval`` compares. The ``abm zoo`` command is :mod:`abm.cli.zoo`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from abm.files import sha256_file

DEFAULT_ZOO = Path("models")
#: the methods ``abm zoo eval`` compares, one model of each (:func:`pick`)
COMPARED_METHODS = ("abm", "rvt")


class ZooError(ValueError):
    """The zoo folder is missing, has no index, or a file does not match its recorded checksum."""


def read_index(zoo: Path) -> list[dict[str, Any]]:
    """The zoo's entries (``ZOO/index.json``)."""
    path = zoo / "index.json"
    if not path.is_file():
        raise ZooError(f"no model zoo index at {path}: run `abm experiment run paper_tables` (it exports the "
                       "models and writes the index) or pass --zoo DIR")
    try:
        entries = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ZooError(f"{path} is not valid JSON ({err})") from err
    if not isinstance(entries, list) or not all(isinstance(e, dict) and "name" in e for e in entries):
        raise ZooError(f"{path} must be a list of entries with a 'name'")
    return entries


def entry_path(zoo: Path, entry: dict[str, Any]) -> Path:
    return zoo / str(entry.get("file", entry["name"]))


def file_sha256(path: Path) -> str:
    """sha256 of a file, or of a folder's ``model.safetensors`` (the benchmark CLIP)."""
    return sha256_file(path / "model.safetensors" if path.is_dir() else path)


def verify(zoo: Path, entry: dict[str, Any]) -> Path:
    """The entry's file, after checking it exists and matches its sha256."""
    path = entry_path(zoo, entry)
    if not path.exists():
        raise ZooError(f"{path} is listed in {zoo / 'index.json'} but missing")
    if entry.get("sha256") and file_sha256(path) != entry["sha256"]:
        raise ZooError(f"{path} does not match its recorded sha256 (a partial download or a changed file): "
                       "restore it with git checkout, or re-export it")
    return path


def needs_clip(entry: dict[str, Any]) -> bool:
    """Whether a model grounds or words its instruction with the benchmark CLIP."""
    return entry.get("grounder") == "clip" or entry.get("language") == "clip"


def pick(entries: list[dict[str, Any]], method: str) -> dict[str, Any] | None:
    """The model of ``method`` that ``abm zoo eval`` runs: a CLIP-grounded one when the benchmark CLIP is in the
    zoo too, else one that needs no CLIP; the first such in the index (the experiment report's order).
    ``None`` when the zoo has no runnable model of that method."""
    has_clip = any(e.get("name") == "benchmark-clip" for e in entries)
    mine = [e for e in entries if e.get("method") == method]
    runnable = [e for e in mine if has_clip or not needs_clip(e)]
    grounded = [e for e in runnable if e.get("grounder") == "clip"]
    return (grounded or runnable or [None])[0]
