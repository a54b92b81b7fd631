"""The ``target_diagnosis`` report section: what the diagnosis shows of each run that misses a target of an
explaining targets section."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.sections.diagnosis import diagnosis_summary
from abm.experiments.report.sections.targets import checked
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """For every ``targets`` section of the report with ``explain``: a paragraph on what the diagnosis shows of
    each run that misses one of its targets (nothing when every target is met)."""
    out = []
    for targets in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if targets.kind != "targets" or not targets.explain:
            continue
        _, missed = checked(ctx, targets)
        if missed:
            out.append("Where a target is missed, the diagnosis shows: " + " ".join(
                f"{run} (misses {', '.join(texts)}): {diagnosis_summary(ctx, run)}." for run, texts in missed.items()))
    return out
