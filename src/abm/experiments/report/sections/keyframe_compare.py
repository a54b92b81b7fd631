"""The ``keyframe_compare`` report section: rotation / position error per task, split and kind, a column per run."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import KIND_ORDER
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Median rotation error (°) / position error (cm) per task, split and keyframe kind, one column per run."""
    runs = section.runs or tuple(ctx.outcomes.summaries)
    found: dict[tuple[str, str, str], dict[str, Mapping[str, Any]]] = {}
    for run in runs:
        for r in ctx.outcomes.summaries.get(run, []):
            if not section.kinds or r["kind"] in section.kinds:
                found.setdefault((r["task"], r["split"], r["kind"]), {})[run] = r
    if not found:
        return []
    order = ctx.task_order()
    lines = table_head(["task", "split", "keyframe", *(section.names.get(r, r) for r in runs)])
    for (task, split, kind), by_run in sorted(found.items(), key=lambda kv: (
            order.get(kv[0][0], 99), kv[0][0], kv[0][1], KIND_ORDER.get(kv[0][2], 9))):
        lines.append(table_row([task, split, kind] + [
            f"{hit['rotation_deg_median']:.0f} / {hit['position_cm_median']:.1f}" if (hit := by_run.get(run))
            else "–" for run in runs]))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
