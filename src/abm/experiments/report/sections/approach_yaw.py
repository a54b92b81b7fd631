"""The ``approach_yaw`` report section: each run's rotation error at the approach keyframe against the grasp's."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import approach_yaw
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    out = []
    for split in section.splits or ("seen",):
        text = approach_yaw(ctx.outcomes.summaries, split, section.task or "place_food")
        if text:
            out.append(text + (f" {section.note}" if section.note else ""))
    return out
