"""The ``per_run`` report section: a table of the runs (rows) by the tasks of one split, with the average."""

from __future__ import annotations

from abm.experiments.report.context import Context, paper_cells
from abm.experiments.report.numbers import cell, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs; columns: the tasks of one split, the average and the paper's."""
    split = section.splits[0]
    tasks = ctx.tasks(split)
    head = [section.column or "method", *tasks, "average"] + (["paper average"] if section.paper else [])
    lines = table_head(head)
    for r in section.runs:
        row = [ctx.label(r)] + [cell(ctx.cells.get((r, t, split))) for t in tasks]
        row.append(ctx.average_shown(r, split, section.spread, section.digits))
        if section.paper:
            row += paper_cells(section, r, 1)
        lines.append(table_row(row))
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(section)
