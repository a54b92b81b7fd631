"""The ``skill_text_table`` report section: one skill-text probe's table (every skill text at the probed keyframe,
the scene's own in bold) from its kept JSON (``source``: the ``out`` file of
:class:`abm.evaluation.diagnose.skill_text.SkillTextProbe`)."""

from __future__ import annotations

import json

from abm.evaluation.diagnose.skill_text import table
from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The probe's table under the section's title (nothing while its JSON is missing)."""
    path = ctx.layout.root / section.source
    if not path.is_file():
        return []
    return [section.title, table(json.loads(path.read_text())["rows"])]
