"""``abm zoo list`` and ``abm zoo eval`` (the parser: :mod:`abm.cli.zoo`; the zoo itself: :mod:`abm.zoo`; its
evaluation: :func:`abm.evaluation.session.evaluate_zoo`)."""

from __future__ import annotations

import argparse

from abm.evaluation import session
from abm.zoo import ZooError, read_index, verify

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


def evaluate_zoo(args: argparse.Namespace) -> int:
    session.evaluate_zoo(args.zoo, args.out, args.tasks, args.episodes, args.workers, args.max_steps, args.models)
    return 0
