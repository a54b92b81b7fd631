"""The ``grounding_quality`` report section: mask quality of one grounding configuration on the evaluated tasks."""

from __future__ import annotations

import json

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Mask quality of one grounding configuration on the evaluated tasks' scenes (the records of
    ``benchmarks/grounding_quality.py``)."""
    path = ctx.layout.root / section.source
    if not path.is_file():
        return []
    tasks = sorted({t for s in ctx.spec.evaluation.splits for t in s.tasks})
    rows = [r for r in json.loads(path.read_text()).get("records", []) if r["config"] == section.config
            and r["task"] in tasks]
    if not rows:
        return []
    lines = table_head(["task", "split", "scenes", "mask IoU", "hit rate", "top-1 point on the target"])
    for t in tasks:
        for s in ("seen", "unseen"):
            for r in (r for r in rows if r["task"] == t and r["split"] == s):
                lines.append(f"| {t} | {s} | {r['n']} | {r['iou']:.2f} | {100 * r['hit_rate']:.0f} % | "
                             f"{100 * r['top1']:.0f} % |")
    return [section.title.format(config=section.config), "\n".join(lines)]
