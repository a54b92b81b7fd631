"""The committed model zoo (``models/``): its index (``models/index.json``), the sha256 checks of its files and
the choice of the entries ``abm zoo eval`` compares. The ``abm zoo`` command is :mod:`abm.cli.zoo`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from abm.files import sha256_file

DEFAULT_ZOO = Path("models")
#: preference order of the abm and rvt entries ``abm zoo eval`` compares
ABM_ENTRIES = ("abm_clip", "abm_oracle")
RVT_ENTRIES = ("rvt_clip",)


class ZooError(ValueError):
    """The zoo folder is missing, has no index, or a file does not match its recorded checksum."""


def read_index(zoo: Path) -> list[dict[str, Any]]:
    """The zoo's entries (``ZOO/index.json``)."""
    path = zoo / "index.json"
    if not path.is_file():
        raise ZooError(f"no model zoo index at {path}: run scripts/paper_tables.sh (it exports the models and "
                       "writes the index) or pass --zoo DIR")
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


def pick(entries: list[dict[str, Any]], names: tuple[str, ...]) -> dict[str, Any] | None:
    """The first entry of ``names`` in the zoo whose CLIP (when it needs one) is there too."""
    by_name = {e["name"]: e for e in entries}
    for name in names:
        e = by_name.get(name)
        if e is None:
            continue
        if e.get("grounder") == "clip" or e.get("language") == "clip":
            if "benchmark-clip" not in by_name:
                continue
        return e
    return None
