"""The ``headline`` report section: the result in a paragraph and a small table, ours beside the paper's; the
paragraph's differences between rows can say whether each exceeds a table's seed spread."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import pct, table_head, table_row
from abm.experiments.report.sections.seeds import seed_spread
from abm.experiments.spec import SPREAD_FIELD, Section, difference_field, template_fields


def against_spread(difference: float | None, spread: float | None, digits: int) -> str:
    """How a difference (points) stands against a seed spread (points): ``more than the seed spread of N points``
    when larger, else ``within the seed spread of N points`` ("–" while either is not measured)."""
    if difference is None or spread is None:
        return "–"
    return f"{'more than' if abs(difference) > spread else 'within'} the seed spread of {spread:.{digits}f} points"


def write(ctx: Context, section: Section) -> list[str]:
    """The result in one paragraph and a small table: the section's text with its placeholders
    (:func:`abm.experiments.spec.headline_fields`: ``{RUN_SPLIT}`` the run's average, %, ``{RUN_SPLIT_paper}`` the
    paper's, ``{RUN_SPLIT_minus_OTHER}`` the run's average less another row's, points, and with ``of_table``
    ``{RUN_SPLIT_minus_OTHER_vs_spread}``, :func:`against_spread` with that table's seed spread on the split)
    filled in once every one it uses is known, then one row per run and source (ours, the paper's) with a column
    per split."""
    digits = section.digits
    spread = seed_spread(ctx, section.of_table) if section.of_table is not None else {}
    values: dict[str, str] = {}
    for run in section.runs:
        paper = section.paper.get(run, ())
        for i, split in enumerate(section.splits):
            values[f"{run}_{split}"] = pct(ctx.average(run, split), digits)
            values[f"{run}_{split}_paper"] = f"{paper[i]:.{digits}f}" if i < len(paper) else "–"
            for other in (r for r in section.runs if r != run):
                mine, theirs = ctx.average(run, split), ctx.average(other, split)
                difference = None if mine is None or theirs is None else mine - theirs
                field = difference_field(run, split, other)
                values[field] = pct(difference, digits)
                if section.of_table is not None:
                    values[field + SPREAD_FIELD] = against_spread(difference, spread.get(split), digits)
    lines = table_head([section.column or "method", *section.splits])
    for run in section.runs:
        name = section.names.get(run, ctx.label(run))
        lines.append(table_row([f"{name}, ours", *(values[f"{run}_{s}"] for s in section.splits)]))
        if run in section.paper:
            lines.append(table_row([f"{name}, paper", *(values[f"{run}_{s}_paper"] for s in section.splits)]))
    known = all(values[name] != "–" for name in template_fields(section.text))
    return ([section.text.format(**values)] if section.text and known else []) + ["\n".join(lines)]
