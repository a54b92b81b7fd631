"""The ``probe_fit`` report section: a probe's yaw fit on its training keyframes per step and arm
(:mod:`abm.experiments.report.probe`)."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.report.probe import arms, probe_records
from abm.experiments.spec import Section

#: the keyframe kinds of the fit table's columns (``all``: the mean over every training keyframe)
FIT_KINDS = ("all", "approach", "grasp", "move", "place")


def write(ctx: Context, section: Section) -> list[str]:
    """Mean yaw cross-entropy (nats) over both tasks, augmentation on: a row per step and arm (an arm without a
    fit at that step has no row), a column per keyframe kind."""
    rows = [r for r in probe_records(ctx, section, "fit") if r["augment"] and r["task"] == "all"]
    if not rows:
        return []
    lines = table_head(["step", "arm", *("all keyframes" if k == "all" else k for k in FIT_KINDS)])
    for step in sorted({r["step"] for r in rows}):
        for arm in arms(ctx, section):
            ce = {r["keyframe"]: r["yaw_ce"] for r in rows if r["arm"] == arm and r["step"] == step}
            if ce:
                lines.append(table_row([str(step), arm, *(f"{ce[k]:.2f}" for k in FIT_KINDS)]))
    return [section.title, "\n".join(lines)]
