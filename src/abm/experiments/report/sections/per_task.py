"""The ``per_task`` report section: a table of the tasks (rows) by every run and split (columns), with averages."""

from __future__ import annotations

from abm.experiments.report.context import Context, paper_cells
from abm.experiments.report.numbers import cell, pct, ratio, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Rows: the tasks of the first split; columns: every run × split; then averages, unseen / seen and the
    paper's averages."""
    runs, splits = section.runs, section.splits
    head = [section.column or "task"] + [f"{ctx.label(r)} {s}" for r in runs for s in splits]
    lines = table_head(head)
    for t in ctx.tasks(splits[0]):
        lines.append(table_row([t] + [cell(ctx.cells.get((r, t, s))) for r in runs for s in splits]))
    avg = [[ctx.average(r, s) for s in splits] for r in runs]
    lines.append("| **average** | " + " | ".join(f"**{pct(avg[i][j])}**" + ctx.error_shown(r, s, section.spread)
                                                  for i, r in enumerate(runs) for j, s in enumerate(splits)) + " |")
    if tuple(splits) == ("seen", "unseen"):
        lines.append("| unseen / seen | " + " | ".join(x for pair in avg for x in ("", ratio(*pair))) + " |")
    if section.paper:
        lines.append("| paper average | " + " | ".join(x for r in runs for x in paper_cells(section, r, len(splits)))
                     + " |")
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(section)
