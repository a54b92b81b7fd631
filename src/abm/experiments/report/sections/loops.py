"""The ``loops`` report section: episodes with a grasp <-> lift loop per row and split."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Episodes with a grasp <-> lift loop (:func:`abm.experiments.arm_records.loops`) per row and split, summed
    over the tasks: ``loops / episodes (%)``."""
    runs = section.runs or tuple(dict.fromkeys(name for name, _, _ in ctx.outcomes.loops))
    splits = section.splits or tuple(s.split for s in ctx.spec.evaluation.splits)
    if not any(name in runs for name, _, _ in ctx.outcomes.loops):
        return []
    lines = table_head([section.column or "arm", *splits])
    for run in runs:
        shown = []
        for split in splits:
            found = [v for (name, _, s), v in ctx.outcomes.loops.items() if name == run and s == split]
            looped, episodes = sum(k for k, _ in found), sum(n for _, n in found)
            shown.append(f"{looped} / {episodes} ({100 * looped / episodes:.0f} %)" if episodes else "–")
        lines.append(table_row([ctx.label(run), *shown]))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
