"""The ``figures`` report section: the spec's figures as markdown images."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The spec's figures as markdown images (drawn by :func:`draw_figures`)."""
    lines = [f"![{f.alt}]({f.file})" for f in ctx.spec.report.figures if (ctx.layout.root / f.file).is_file()]
    return ["\n".join(lines)] if lines else []
