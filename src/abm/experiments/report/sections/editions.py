"""The ``editions`` report section: each run's averages beside the same run's in the earlier editions' records.

An edition of a table is a spec like ``paper_tables_v2``: the same run names (``abm_clip``, ``rvt_clip``, ...) trained
again with another recipe. This section reads each earlier edition's records JSON (the report's ``records:`` file,
a list of cells ``{run, task, split, mean, ...}``), averages a run's cells over the split's tasks as this report
does (:func:`abm.experiments.report.numbers.average`), and tabulates the editions side by side with this edition's
change from the last of them (points). With ``of_table``, the change is read against that table's seed spread.
"""

from __future__ import annotations

import json
from pathlib import Path
from statistics import mean

from abm.errors import ConfigError
from abm.experiments.report.context import Context
from abm.experiments.report.numbers import Cells, average, pct, table_head, table_row
from abm.experiments.report.sections.seeds import seed_spread
from abm.experiments.spec import Section


def records_cells(path: Path) -> Cells | None:
    """``(run, task, split) -> cell`` of a report's records JSON (a run listed in two tables has the same cell in
    both: the first is kept); ``None`` when the file is not there (a checkout without that edition's results).

    Raises:
        ConfigError: the file is no list of cells.
    """
    if not path.is_file():
        return None
    rows = json.loads(path.read_text())
    if not isinstance(rows, list) or not all(isinstance(r, dict) and {"run", "task", "split", "mean"} <= r.keys()
                                             for r in rows):
        raise ConfigError(f"{path}: expected a list of cells with run, task, split and mean (a report's records)")
    cells: Cells = {}
    for row in rows:
        cells.setdefault((row["run"], row["task"], row["split"]), row)
    return cells


def changes(ctx: Context, section: Section,
            earlier: list[Cells | None]) -> dict[tuple[str, str], tuple[list[float | None], float | None]]:
    """``(run, split) -> (the earlier editions' averages, oldest first; this edition's)``, ``None`` where not
    evaluated (or the edition's records are missing)."""
    return {(run, split): ([None if cells is None else average(cells, run, split, ctx.tasks(split))
                            for cells in earlier], ctx.average(run, split))
            for run in section.runs for split in section.splits}


def write(ctx: Context, section: Section) -> list[str]:
    """Rows: run and split; columns: each earlier edition's average, this edition's, and the change from the last
    earlier edition; then the mean change per split over the runs evaluated in both."""
    digits = section.digits
    labels = list(section.earlier)
    last = labels[-1]
    lines = table_head(["run", "split", *labels, "this edition", f"change from the {last}"])
    earlier = [records_cells(ctx.layout.root / path) for path in section.earlier.values()]
    moved: dict[str, list[float]] = {}
    for (run, split), (before, now) in changes(ctx, section, earlier).items():
        if now is None and all(v is None for v in before):
            continue
        change = None if now is None or before[-1] is None else now - before[-1]
        if change is not None:
            moved.setdefault(split, []).append(change)
        shown = "–" if change is None else f"{change:+.{digits}f}"
        lines.append(table_row([section.names.get(run, run), split, *(pct(v, digits) for v in before),
                                pct(now, digits), shown]))
    spread = seed_spread(ctx, section.of_table) if section.of_table is not None else {}
    parts = []
    for split in section.splits:
        if split not in moved:
            continue
        part = f"{split} {mean(moved[split]):+.{digits}f} points over {len(moved[split])} run(s)"
        if split in spread:
            part += f" (Table {section.of_table}'s seed spread: {spread[split]:.{digits}f})"
        parts.append(part)
    missing = [f"{label} ({path})" for (label, path), cells in zip(section.earlier.items(), earlier, strict=True)
               if cells is None]
    text = (f"Success % averaged over each split's tasks, per edition; the change is this edition's average less "
            f"the {last}'s. Mean change: " + ("; ".join(parts) if parts else "none measured yet") + "." +
            (f" Not in this checkout, so shown as –: the records of the {', '.join(missing)}." if missing else ""))
    return [section.title, "\n".join(lines), text] if section.title else ["\n".join(lines), text]
