"""The ``missing`` report section: the rows not evaluated."""

from __future__ import annotations

from abm.experiments.report.context import Context, evaluated
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The rows not evaluated (e.g. runs left out with --runs)."""
    missing = [ctx.label(n) for n in section.runs if not evaluated(ctx, n)]
    return [f"{section.text or 'Not evaluated'}: {', '.join(missing)}."] if missing else []
