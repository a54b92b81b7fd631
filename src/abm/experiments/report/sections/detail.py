"""The ``detail`` report section: every run on every task of the splits."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import cell, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Every run (or the section's) on every task of the splits."""
    runs = section.runs or tuple(ctx.spec.runs)
    splits = section.splits or ("seen", "unseen")
    lines = table_head(["run"] + [f"{t} {s}" for s in splits for t in ctx.tasks(s)])
    for r in runs:
        lines.append(table_row([r] + [cell(ctx.cells.get((r, t, s))) for s in splits for t in ctx.tasks(s)]))
    return ["\n".join(lines)]
