"""The ``headline`` report section: the result in a paragraph and a small table, ours beside the paper's."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import pct, table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The result in one paragraph and a small table: the section's text with ``{RUN_SPLIT}`` (the run's
    average, %) and ``{RUN_SPLIT_paper}`` (the paper's) filled in once every one is known, then one row per run
    and source (ours, the paper's) with a column per split."""
    digits = section.digits
    values: dict[str, str] = {}
    for run in section.runs:
        paper = section.paper.get(run, ())
        for i, split in enumerate(section.splits):
            values[f"{run}_{split}"] = pct(ctx.average(run, split), digits)
            values[f"{run}_{split}_paper"] = f"{paper[i]:.{digits}f}" if i < len(paper) else "–"
    lines = table_head([section.column or "method", *section.splits])
    for run in section.runs:
        name = section.names.get(run, ctx.label(run))
        lines.append(table_row([f"{name}, ours", *(values[f"{run}_{s}"] for s in section.splits)]))
        if run in section.paper:
            lines.append(table_row([f"{name}, paper", *(values[f"{run}_{s}_paper"] for s in section.splits)]))
    known = "–" not in values.values()
    return ([section.text.format(**values)] if section.text and known else []) + ["\n".join(lines)]
