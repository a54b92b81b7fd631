"""The committed model zoo (``models/``): its index (``models/index.json``, written by the reports of
``abm experiment run paper_tables`` and of its later editions, ``paper_tables_v2``), the sha256 checks of its
files and the choice of the entries ``abm zoo eval`` compares. The ``abm zoo`` command is :mod:`abm.cli.zoo`.

Editions: a later edition of an experiment exports its models beside the earlier ones under other names
(``abm_clip_v2.pt``), so every model stays loadable; its entries record their ``edition`` (none: the first) and
mark the models ``abm zoo eval`` compares (``compared``), and :func:`pick` takes the newest edition's.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from abm.errors import DataError
from abm.files import is_inside, sha256_file
from abm.grounding.config import as_grounder_config
from abm.policy.language_config import as_language_config

DEFAULT_ZOO = Path("models")
#: the methods ``abm zoo eval`` compares, one model of each (:func:`pick`)
COMPARED_METHODS = ("abm", "rvt")


class ZooError(DataError):
    """The zoo folder is missing, has no index, an index entry cannot be trusted (no sha256, a file outside the
    zoo, a size that is not a number), or a file does not match its recorded checksum."""


def read_index(zoo: Path) -> list[dict[str, Any]]:
    """The zoo's entries (``ZOO/index.json``), each checked (:func:`check_entry`).

    Raises:
        ZooError: one line naming the index, the entry and the fix: no index, not JSON, not a list of entries,
            or an entry without a sha256, with a file outside the zoo folder or a size that is not a number.
    """
    path = zoo / "index.json"
    if not path.is_file():
        raise ZooError(f"no model zoo index at {path}: run `abm experiment run paper_tables` (it exports the "
                       "models and writes the index) or pass --zoo DIR")
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ZooError(f"{path} is not valid JSON ({err}): restore it with git checkout, or rewrite it with "
                       "abm experiment run paper_tables") from None
    if not isinstance(entries, list):
        raise ZooError(f"{path} must be a list of entries (objects with a 'name', a 'file' and its 'sha256'), got "
                       f"{type(entries).__name__}: restore it with git checkout")
    for i, entry in enumerate(entries):
        check_entry(zoo, entry, f"{path}: entry {i}")
    return entries


_SHA256 = re.compile(r"[0-9a-f]{64}")


def check_entry(zoo: Path, entry: object, where: str) -> None:
    """Raise :class:`ZooError` (starting with ``where``) unless ``entry`` is an index entry abm can trust: a
    ``name``, a ``file`` (default: the name) that stays inside the zoo folder, the file's ``sha256``, and
    numbers where the listing reads them (``size_bytes``, ``steps``)."""
    if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or not entry["name"].strip():
        raise ZooError(f"{where}: expected an object with a 'name' (text), got {entry!r:.80}: fix the entry, or "
                       "restore the index with git checkout")
    where = f"{where} ({entry['name']})"
    file = entry.get("file", entry["name"])
    if not isinstance(file, str) or not file.strip() or Path(file).is_absolute() or not is_inside(zoo / file, zoo) \
            or (zoo / file).resolve() == zoo.resolve():
        raise ZooError(f"{where}: 'file' {file!r} points outside the zoo folder {zoo}; an entry names a file inside "
                       "it (e.g. 'abm_clip.pt'), so fix the entry or restore the index with git checkout")
    digest = entry.get("sha256")
    if not isinstance(digest, str) or not _SHA256.fullmatch(digest):
        got = "has no 'sha256'" if digest is None else f"has 'sha256' {digest!r:.80}, not 64 hex digits"
        raise ZooError(f"{where} {got}; every zoo file is checked against the sha256 of its bytes: add it "
                       f"(sha256sum {zoo / file}) or rewrite the index with abm experiment run paper_tables")
    for key in ("size_bytes", "steps", "edition"):
        value = entry.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
            raise ZooError(f"{where}: {key!r} is {value!r:.80}, expected a whole number >= 0: fix the entry, or "
                           "rewrite the index with abm experiment run paper_tables")


def entry_path(zoo: Path, entry: dict[str, Any]) -> Path:
    return zoo / str(entry.get("file", entry["name"]))


def file_sha256(path: Path) -> str:
    """sha256 of a file, or of a folder's ``model.safetensors`` (the benchmark CLIP)."""
    return sha256_file(path / "model.safetensors" if path.is_dir() else path)


def verify(zoo: Path, entry: dict[str, Any]) -> Path:
    """The entry's file, after checking the entry (:func:`check_entry`), that the file exists and that it
    matches its sha256."""
    check_entry(zoo, entry, f"{zoo / 'index.json'}: entry")
    path = entry_path(zoo, entry)
    if not path.exists():
        raise ZooError(f"{path} is listed in {zoo / 'index.json'} but missing: restore it with git checkout, or "
                       "re-export it")
    if file_sha256(path) != entry["sha256"]:
        raise ZooError(f"{path} does not match its recorded sha256 (a partial download or a changed file): "
                       "restore it with git checkout, or re-export it")
    return path


def grounds_with_clip(entry: dict[str, Any]) -> bool:
    """Whether a model's grounder (its ``grounder_spec``) uses a CLIP."""
    return as_grounder_config(entry.get("grounder_spec")).clip_model() is not None


def needs_clip(entry: dict[str, Any]) -> bool:
    """Whether a model grounds or words its instruction (its ``language`` kind) with a CLIP: the benchmark CLIP."""
    language = entry.get("language")
    return grounds_with_clip(entry) or (language is not None and as_language_config(language).clip_model() is not None)


def edition(entry: dict[str, Any]) -> int:
    """The edition of an entry's model (1: the first edition's entries, which record none)."""
    value = entry.get("edition", 1)
    return value if isinstance(value, int) and not isinstance(value, bool) else 1


def named(entries: list[dict[str, Any]], names: Sequence[str]) -> list[dict[str, Any]]:
    """The entries of ``names``, in that order (``abm zoo eval --models``: e.g. an edition's models before its
    README gate makes them the ones :func:`pick` takes).

    Raises:
        ZooError: a name the index does not list, or one that needs the benchmark CLIP when the zoo has none.
    """
    by_name = {e.get("name"): e for e in entries}
    has_clip = "benchmark-clip" in by_name
    chosen = []
    for name in names:
        entry = by_name.get(name)
        if entry is None or name == "benchmark-clip":
            models = ", ".join(str(e.get("name")) for e in entries if e.get("name") != "benchmark-clip")
            raise ZooError(f"{name!r} is no model of the zoo's index (it lists {models})")
        if not has_clip and needs_clip(entry):
            raise ZooError(f"{name} grounds or words its instruction with the benchmark CLIP, which the zoo does "
                           "not hold (benchmark-clip)")
        chosen.append(entry)
    return chosen


def pick(entries: list[dict[str, Any]], method: str) -> dict[str, Any] | None:
    """The model of ``method`` that ``abm zoo eval`` runs, among those it can run (a CLIP-grounded or CLIP-worded
    one needs the benchmark CLIP in the zoo too): the newest edition's model marked ``compared`` when one is
    in the zoo (an experiment's ``evaluation.zoo_eval`` runs); else, from the first edition's models (all
    models when it has none), a CLIP-grounded one, else one that needs no CLIP, the first such in the index
    (the experiment report's order). ``None`` when the zoo has no runnable model of that method."""
    has_clip = any(e.get("name") == "benchmark-clip" for e in entries)
    mine = [e for e in entries if e.get("method") == method]
    runnable = [e for e in mine if has_clip or not needs_clip(e)]
    compared = [e for e in runnable if e.get("compared") is True]
    if compared:
        newest = max(edition(e) for e in compared)
        return next(e for e in compared if edition(e) == newest)
    first = [e for e in runnable if edition(e) == 1] or runnable
    grounded = [e for e in first if grounds_with_clip(e)]
    return (grounded or first)[0] if grounded or first else None
