"""The ``averages`` report section: a table of the runs' seen and unseen averages and their ratio."""

from __future__ import annotations

from dataclasses import replace

from abm.experiments.report.context import Context, paper_cells
from abm.experiments.report.numbers import ratio, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs; columns: seen and unseen averages, their ratio and the paper's."""
    head = [section.column or "run", "seen avg", "unseen avg", "unseen / seen"]
    head += ["paper seen", "paper unseen"] if section.paper else []
    lines = table_head(head)
    for r in section.runs:
        seen, unseen = ctx.average(r, "seen"), ctx.average(r, "unseen")
        row = [section.names.get(r, r), ctx.average_shown(r, "seen", section.spread),
               ctx.average_shown(r, "unseen", section.spread), ratio(seen, unseen)]
        if section.paper:
            row += paper_cells(section, r, 2)
        lines.append(table_row(row))
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(replace(section, splits=section.splits or ("seen", "unseen")))
