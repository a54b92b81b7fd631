"""The ``keyframe_rows`` report section: final-checkpoint keyframe accuracy per method, task, split and kind."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import KIND_ORDER, final_rows
from abm.experiments.report.numbers import table_head
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Final-checkpoint accuracy per method, task, split and keyframe kind."""
    rows = [r for r in final_rows(ctx) if not section.kinds or r["kind"] in section.kinds]
    if not rows:
        return []
    lines = table_head(["method", "task", "split", "keyframe", "position error cm (median)", "within 2 cm",
                        "rotation error ° (median)"])
    for r in sorted(rows, key=lambda r: (r["task"], KIND_ORDER.get(r["kind"], 9), r["kind"], r["split"],
                                         r["method"])):
        lines.append(f"| {r['method']} | {r['task']} | {r['split']} | {r['kind']} | {r['position_cm_median']:.1f} | "
                     f"{100 * r['within_grasp_tolerance']:.0f} % | {r['rotation_deg_median']:.0f} |")
    title = section.title.format(episodes=ctx.spec.diagnose.episodes if ctx.spec.diagnose else "?")
    return [title, "\n".join(lines)] if title else ["\n".join(lines)]
