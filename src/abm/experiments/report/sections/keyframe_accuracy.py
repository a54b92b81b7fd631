"""The ``keyframe_accuracy`` report section: per split: a heading, the weakest keyframes and the keyframe table of
every diagnosis."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import keyframe_table, weakest_keyframes
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Per split with diagnosis rows: a heading, the weakest keyframes, the section's text and the table."""
    summaries = ctx.outcomes.summaries
    out = []
    for split in section.splits or ("seen", "unseen"):
        if any(row["split"] == split for rows in summaries.values() for row in rows):
            out += [f"## Keyframe accuracy, {split} objects", weakest_keyframes(summaries, split), section.text,
                    keyframe_table(summaries, split, ctx.task_order())]
    return [b for b in out if b]
