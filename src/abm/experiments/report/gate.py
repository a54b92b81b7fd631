"""The gate of a report's README blocks and zoo README (``report.readme_when``,
:class:`abm.experiments.spec.ReadmeGate`): a spec declares them before it has results, and the report writes them
only once the tables the gate names are complete; until then it leaves the README and the zoo's README as they are
(the earlier edition's). :func:`waits` says what the gate waits for (the report's log, ``abm experiment status``).

A table is complete when every cell it needs is evaluated (:func:`needed_cells`): each of its rows on every task of
each of its splits, and the runs of its seed pairs (its ``seeds`` sections) on theirs, so the README's
differences can be held to the seed spread.
"""

from __future__ import annotations

from collections.abc import Sequence

from abm.experiments.report.context import Context, table_section
from abm.experiments.report.sections.seeds import seed_splits
from abm.experiments.spec import ExperimentSpec
from abm.experiments.state import Layout


def needed_cells(ctx: Context, table: int) -> list[tuple[str, str, str]]:
    """``(run, task, split)`` of every cell table ``table`` needs evaluated before it counts as complete."""
    rows = table_section(ctx, table)
    pairs = [(run, split) for run in rows.runs for split in rows.splits]
    for section in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if section.kind == "seeds" and section.of_table == table:
            pairs += [(run, split) for pair in section.seeds.items() for run in pair
                      for split in seed_splits(ctx, section)]
    return list(dict.fromkeys((run, task, split) for run, split in pairs for task in ctx.tasks(split)))


def progress(ctx: Context) -> dict[int, tuple[int, int]]:
    """Table -> (cells evaluated, cells needed) of every table the gate names (``{}`` without a gate)."""
    gate = ctx.spec.report.readme_when
    found = {}
    for table in gate.complete if gate is not None else ():
        needed = needed_cells(ctx, table)
        found[table] = (sum(cell in ctx.cells for cell in needed), len(needed))
    return found


def tables(numbers: Sequence[int]) -> str:
    """``Table 1``, ``Tables 1 and 2``, ``Tables 1, 2 and 3``."""
    shown = [str(n) for n in numbers]
    return f"Table{'s' if len(shown) > 1 else ''} " + (
        shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} and {shown[-1]}")


def held_back(spec: ExperimentSpec, layout: Layout) -> str:
    """What the gate holds back: ``README.md's paper-tables and headline blocks and models/README.md``."""
    report, parts = spec.report, []
    if report.readme:
        names = [report.block, *report.blocks]
        parts.append(f"{report.readme}'s {' and '.join(names)} block{'s' if len(names) > 1 else ''}")
    if report.zoo_readme and layout.zoo is not None:
        parts.append(layout.show(layout.zoo / "README.md"))
    return " and ".join(parts)


def waits(ctx: Context) -> str:
    """What the gate waits for (``""``: open, or no gate): ``Tables 1 and 2 are complete (Table 1: 12 of 112 cells
    evaluated, its seed pairs' included; Table 2: 0 of 10)``."""
    found = progress(ctx)
    open_ = [n for n, (done, needed) in found.items() if done < needed]
    if not open_:
        return ""
    seeded = {s.of_table for s in (*ctx.spec.report.summary, *ctx.spec.report.details) if s.kind == "seeds"}
    counts = [f"Table {n}: {found[n][0]} of {found[n][1]}{' cells evaluated' if i == 0 else ''}"
              + (", its seed pairs' included" if n in seeded else "") for i, n in enumerate(open_)]
    return f"{tables(list(found))} {'are' if len(found) > 1 else 'is'} complete ({'; '.join(counts)})"


def status_line(ctx: Context) -> list[str]:
    """The gate as ``abm experiment status`` shows it (``[]`` without a gate)."""
    gate = ctx.spec.report.readme_when
    if gate is None:
        return []
    what = held_back(ctx.spec, ctx.layout)
    waiting = waits(ctx)
    if waiting:
        return [f"README gate (report.readme_when): closed: the report leaves {what} unchanged until {waiting}"]
    return [f"README gate (report.readme_when): open ({tables(gate.complete)} complete): the report writes {what}"]
