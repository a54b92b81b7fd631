"""The ``caveats`` report section: the caveats of the runs that have cells."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The caveats of the runs that have cells, as one paragraph."""
    runs = {run for run, _, _ in ctx.cells}
    notes = [run.caveat for name, run in ctx.spec.runs.items() if run.caveat and name in runs]
    return [" ".join(notes)] if notes else []
