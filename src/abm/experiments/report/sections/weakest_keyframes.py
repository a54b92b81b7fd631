"""The ``weakest_keyframes`` report section: each run's keyframe kinds by position error, worst first."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import weakest_keyframes
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    return [t for s in section.splits or ("seen",) if (t := weakest_keyframes(ctx.outcomes.summaries, s))]
