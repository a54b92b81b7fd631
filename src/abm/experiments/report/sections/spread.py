"""The ``spread`` report section: a sentence: the range of a table's averages beside the paper's."""

from __future__ import annotations

from abm.experiments.report.context import Context, table_section
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """One sentence once every run of a table has both averages: their range beside the paper's."""
    table = table_section(ctx, section.of_table)
    seen = [ctx.average(r, "seen") for r in table.runs]
    unseen = [ctx.average(r, "unseen") for r in table.runs]
    if any(v is None for v in (*seen, *unseen)):
        return []
    ours = [f"{min(v):.1f}–{max(v):.1f}" for v in (seen, unseen)]  # type: ignore[type-var]
    paper = [f"{min(v)}–{max(v)}" for v in zip(*(table.paper[r] for r in table.runs), strict=True)]
    return [section.text.format(seen=ours[0], unseen=ours[1], paper_seen=paper[0], paper_unseen=paper[1])]
