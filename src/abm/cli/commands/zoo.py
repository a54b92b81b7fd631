"""``abm zoo list`` and ``abm zoo eval`` (the parser: :mod:`abm.cli.zoo`; the zoo itself: :mod:`abm.zoo`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from abm.errors import ExternalError
from abm.evaluation.policies import checkpoint_clips
from abm.evaluation.results import EpisodeOutcome, markdown_table
from abm.evaluation.runner import crash_summary, evaluate
from abm.evaluation.settings import EvalSettings
from abm.zoo import COMPARED_METHODS, ZooError, entry_path, pick, read_index, verify

LIST_COLUMNS = ("name", "method", "grounder", "steps", "MB", "check")
RIGHT_ALIGNED = frozenset({"steps", "MB"})


def aligned_rows(rows: list[tuple[str, ...]]) -> list[str]:
    """``rows`` (the header first) as text lines whose columns line up, each column as wide as its longest cell
    (numbers right-aligned, the last column left as it is)."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(LIST_COLUMNS) - 1)]
    return [" ".join(cell.rjust(w) if col in RIGHT_ALIGNED else cell.ljust(w)
                     for col, cell, w in zip(LIST_COLUMNS, row, widths, strict=False)) + "  " + row[-1]
            for row in rows]


def list_zoo(args: argparse.Namespace) -> int:
    entries = read_index(args.zoo)
    rows: list[tuple[str, ...]] = [LIST_COLUMNS]
    bad = 0
    for e in entries:
        try:
            verify(args.zoo, e)
            status = "ok"
        except ZooError as err:
            status, bad = f"FAILED: {err}", bad + 1
        rows.append((str(e["name"]), str(e.get("method", "?")), str(e.get("grounder", "–")),
                     str(e.get("steps", "–")), f"{(e.get('size_bytes') or 0) / 1e6:.1f}", status))
    print("\n".join(aligned_rows(rows)))
    if bad:
        raise ZooError(f"{bad} zoo file(s) failed verification")
    return 0


def check_zoo_clips(zoo: Path, runs: list[Path], clip: dict[str, Any] | None) -> None:
    """Refuse (:class:`ZooError`, before any rollout) a model whose CLIP does not resolve to the zoo's own
    benchmark CLIP. The models name it by the path they were trained with (``models/benchmark-clip``), which is
    looked for relative to the model's folder and its parents, then the working folder
    (:func:`abm.evaluation.policies.clip_root`)."""
    expected = entry_path(zoo, clip).resolve() if clip is not None else None
    for run in runs:
        for name, found in checkpoint_clips(run).items():
            if expected is not None and found is not None and found.resolve() == expected:
                continue
            where = f"resolves to {found}" if found is not None else "is not found"
            instead = f" instead of the zoo's {expected}" if expected is not None else ""
            raise ZooError(f"{run} names its CLIP {name!r}, which {where}{instead} (looked in {run.resolve().parent} "
                           "and its parents, then the working folder): keep the zoo's layout, the models and "
                           f"benchmark-clip/ in one folder named {Path(name).parent.name or 'models'!r} (as in the "
                           "checkout), and pass that folder as --zoo")


def evaluate_zoo(args: argparse.Namespace) -> int:
    entries = read_index(args.zoo)
    chosen = [e for e in (pick(entries, method) for method in COMPARED_METHODS) if e]
    if not chosen:
        raise ZooError(f"{args.zoo} holds no runnable {' or '.join(COMPARED_METHODS)} model (a CLIP-grounded one "
                       "needs the benchmark CLIP in the zoo too)")
    runs = [verify(args.zoo, e) for e in chosen]
    clip = next((e for e in entries if e["name"] == "benchmark-clip"), None)
    if clip is not None:
        verify(args.zoo, clip)
    check_zoo_clips(args.zoo, runs, clip)
    labels = {str(r): e["name"] for r, e in zip(runs, chosen, strict=True)}
    grounders = ", ".join(f"{e['name']}: {e.get('grounder', 'none')}" for e in chosen)
    clip_note = f" (the zoo's {entry_path(args.zoo, clip)}, sha256 verified)" if clip is not None else ""
    print(f"abm zoo eval: grounder: each model's own, as trained ({grounders}){clip_note}")
    settings = EvalSettings(max_steps=args.max_steps)
    rates = []
    outcomes: list[EpisodeOutcome] = []
    for split in ("seen", "unseen"):
        print(f"abm zoo eval: {', '.join(labels.values())} on {split} objects of {', '.join(args.tasks)} "
              f"({args.episodes} episodes each)")
        rates += evaluate(runs, args.tasks, split, args.out / split, args.episodes, 1, args.workers, settings,
                          labels=labels, collect=outcomes)
    table = markdown_table(rates)
    (args.out / "results.md").write_text(table + "\n")
    print(table)
    print(f"results: {args.out / 'results.md'}; the full tables: docs/results/paper_tables.md")
    crashes = crash_summary(outcomes)
    if crashes:  # a crash is not a measurement: the table is written, but the command fails
        raise ExternalError(f"{crashes}; outcomes: {args.out / '{seen,unseen}' / 'outcomes.jsonl'}")
    return 0
