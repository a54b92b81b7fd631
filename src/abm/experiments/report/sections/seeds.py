"""The ``seeds`` report section: the seed spread of a table, and the differences above it."""

from __future__ import annotations

from collections.abc import Mapping

from abm.experiments.report.context import Context, table_section
from abm.experiments.report.numbers import pct, table_head, table_row
from abm.experiments.spec import Section


def seed_spread(ctx: Context, of_table: int | None = None) -> dict[str, float]:
    """split -> the seed spread of every ``seeds`` section of the report (points; of table ``of_table``'s only, when
    given): the largest difference between the averages of two seeds of one run; a split is left out until one
    seed pair has it evaluated."""
    spread: dict[str, float] = {}
    for section in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if section.kind == "seeds" and of_table in (None, section.of_table):
            for split, points in section_spread(seed_differences(ctx, section)).items():
                spread[split] = max(spread.get(split, 0.0), points)
    return spread


def seed_splits(ctx: Context, section: Section) -> tuple[str, ...]:
    return section.splits or table_section(ctx, section.of_table).splits or ("seen", "unseen")


def seed_difference(ctx: Context, run: str, other: str, split: str) -> float | None:
    a, b = ctx.average(run, split), ctx.average(other, split)
    return None if a is None or b is None else abs(a - b)


def seed_differences(ctx: Context, section: Section) -> dict[tuple[str, str], float | None]:
    """(run, split) -> the difference between the averages of a ``seeds`` section's pair (None: not evaluated)."""
    return {(run, split): seed_difference(ctx, run, other, split)
            for run, other in section.seeds.items() for split in seed_splits(ctx, section)}


def section_spread(differences: Mapping[tuple[str, str], float | None]) -> dict[str, float]:
    """split -> the largest of a ``seeds`` section's evaluated differences (:func:`seed_differences`)."""
    spread: dict[str, float] = {}
    for (_, split), difference in differences.items():
        if difference is not None:
            spread[split] = max(spread.get(split, 0.0), difference)
    return spread


def write(ctx: Context, section: Section) -> list[str]:
    """The seed spread of a table: each run beside the same run with another seed (``seeds``), the largest such
    difference per split as the spread, and the differences between the table's rows that exceed it."""
    table = table_section(ctx, section.of_table)
    splits = seed_splits(ctx, section)
    digits = section.digits
    names = {**table.names, **section.names}
    columns = (f"{s} {x}" for s in splits for x in ("avg", "other seed", "difference"))
    lines = table_head(["run", "other seed", *columns])
    differences = seed_differences(ctx, section)
    for run, other in section.seeds.items():
        row = [names.get(run, run), other]
        for split in splits:
            row += [ctx.average_shown(run, split, True, digits), ctx.average_shown(other, split, True, digits),
                    pct(differences[run, split], digits)]
        lines.append(table_row(row))
    spread = section_spread(differences)
    sentences = []
    for split in splits:
        if split not in spread:
            sentences.append(f"{split}: the seed spread is not measured yet (each seed pair needs every task "
                             "evaluated)")
            continue
        averages = {r: v for r in table.runs if (v := ctx.average(r, split)) is not None}
        exceeding = [f"{names.get(a, a)} vs {names.get(b, b)} {abs(averages[a] - averages[b]):.{digits}f}"
                     for i, a in enumerate(averages) for b in list(averages)[i + 1:]
                     if abs(averages[a] - averages[b]) > spread[split]]
        sentences.append(f"{split}: seed spread {spread[split]:.{digits}f} points; differences between the table's "
                         f"rows larger than it: {', '.join(exceeding) if exceeding else 'none'}")
    text = (f"Seed spread of Table {table.table}: the largest difference between the averages of two seeds of one "
            "run (same data, recipe and evaluation scenes; ± the standard error over the repeats). " +
            "; ".join(sentences) + ".")
    return [section.title, "\n".join(lines), text] if section.title else ["\n".join(lines), text]
