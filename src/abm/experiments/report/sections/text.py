"""The ``text`` report section: a paragraph of the spec's text."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    return [section.text] if section.text else []
