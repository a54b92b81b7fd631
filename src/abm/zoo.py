"""``abm zoo``: the committed model zoo (``models/``) — list it, verify it, and see the paper's finding without
training.

* ``abm zoo list`` prints the index (``models/index.json``, written by ``benchmarks/paper_tables_report.py``)
  and checks every file against its recorded sha256;
* ``abm zoo eval`` evaluates the zoo's abm and rvt models on seen and unseen objects of a few tasks through
  the full pipeline (simulator, grounding, policy, executor) and prints one table: about 10 minutes on 2 CPU
  cores with the defaults.

The abm model is the CLIP-grounded one (``abm_clip``) when it and the benchmark CLIP are in the zoo, else
the oracle-grounded one (``abm_oracle``); rvt is ``rvt_clip``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import Any

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
    target = path / "model.safetensors" if path.is_dir() else path
    h = hashlib.sha256()
    with target.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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


def _list(args: argparse.Namespace) -> int:
    entries = read_index(args.zoo)
    print(f"{'name':20s} {'method':18s} {'grounder':18s} {'steps':>6s} {'MB':>6s}  check")
    bad = 0
    for e in entries:
        try:
            verify(args.zoo, e)
            status = "ok"
        except ZooError as err:
            status, bad = f"FAILED: {err}", bad + 1
        print(f"{e['name']:20s} {e.get('method', '?'):18s} {str(e.get('grounder', '–')):18s} "
              f"{str(e.get('steps', '–')):>6s} {e.get('size_bytes', 0) / 1e6:6.1f}  {status}")
    if bad:
        raise ZooError(f"{bad} zoo file(s) failed verification")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from abm.evaluation.results import markdown_table  # heavy (torch, mujoco): only when evaluating
    from abm.evaluation.runner import EvalSettings, evaluate

    entries = read_index(args.zoo)
    chosen = [e for e in (pick(entries, ABM_ENTRIES), pick(entries, RVT_ENTRIES)) if e]
    if not chosen:
        raise ZooError(f"{args.zoo} holds neither an abm ({', '.join(ABM_ENTRIES)}) nor an rvt model "
                       f"({', '.join(RVT_ENTRIES)})")
    runs = [verify(args.zoo, e) for e in chosen]
    clip = next((e for e in entries if e["name"] == "benchmark-clip"), None)
    if clip is not None:
        verify(args.zoo, clip)
    labels = {str(r): e["name"] for r, e in zip(runs, chosen, strict=True)}
    settings = EvalSettings(max_steps=args.max_steps)
    rates = []
    for split in ("seen", "unseen"):
        print(f"abm zoo eval: {', '.join(labels.values())} on {split} objects of {', '.join(args.tasks)} "
              f"({args.episodes} episodes each)")
        rates += evaluate(runs, args.tasks, split, args.out / split, args.episodes, 1, args.workers, settings,
                          labels=labels)
    table = markdown_table(rates)
    (args.out / "results.md").write_text(table + "\n")
    print(table)
    print(f"results: {args.out / 'results.md'}; the full tables: docs/results/paper_tables.md")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    from abm.configuration import int_range

    p = subparsers.add_parser("zoo", help="the committed model zoo: list and verify it, or evaluate its models",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="zoo_command", metavar="ZOO_COMMAND", required=True)
    lst = sub.add_parser("list", help="print the zoo's models and verify their sha256")
    lst.add_argument("--zoo", type=Path, default=DEFAULT_ZOO, help=f"zoo folder (default {DEFAULT_ZOO})")
    lst.set_defaults(func=_list)
    ev = sub.add_parser("eval", help="evaluate the zoo's abm and rvt models on seen and unseen objects (~10 min)")
    ev.add_argument("--zoo", type=Path, default=DEFAULT_ZOO, help=f"zoo folder (default {DEFAULT_ZOO})")
    ev.add_argument("--tasks", nargs="+", default=["pick_block", "close_jar"],
                    help="tasks to evaluate (default: pick_block close_jar)")
    ev.add_argument("--episodes", type=int_range(1, 10_000), default=5,
                    help="seeded episodes per task and split (default 5)")
    ev.add_argument("--workers", type=int_range(1, 256), default=2, help="parallel rollout processes (default 2)")
    ev.add_argument("--max-steps", type=int_range(1, 100), default=8, help="keyframes per episode (default 8)")
    ev.add_argument("--out", type=Path, default=Path("out/zoo"), help="output folder (default out/zoo)")
    ev.set_defaults(func=_eval)
