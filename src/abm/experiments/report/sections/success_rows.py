"""The ``success_rows`` report section: the runs and variants evaluated by every task and split, with averages."""

from __future__ import annotations

from abm.experiments.report.context import Context, evaluated
from abm.experiments.report.numbers import cell, pct, ratio, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs and variants evaluated; columns: (method and target,) every task × split, the split
    averages and unseen / seen."""
    splits = section.splits or ("seen", "unseen")
    head = [section.column or "run"] + (["method", "target from"] if section.describe else [])
    head += [f"{t} {s}" for s in splits for t in ctx.tasks(s)] + [f"{s} avg" for s in splits]
    both = "seen" in splits and "unseen" in splits
    lines = table_head(head + (["unseen / seen"] if both else []))
    for name in section.runs:
        if not evaluated(ctx, name):
            continue
        row = [ctx.label(name)]
        if section.describe:
            row += [ctx.method(name), ctx.describe(name)]
        row += [cell(ctx.cells.get((name, t, s))) for s in splits for t in ctx.tasks(s)]
        row += [pct(ctx.average(name, s), section.digits) for s in splits]
        if both:
            row.append(ratio(ctx.average(name, "seen"), ctx.average(name, "unseen")))
        lines.append(table_row(row))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
