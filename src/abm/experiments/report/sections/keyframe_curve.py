"""The ``keyframe_curve`` report section: a keyframe kind's position error against training steps."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """A keyframe kind's position error (seen objects; per task the median, then the mean over tasks) against
    training steps, with the training minutes at each step (``minutes_at_steps`` of the run summaries)."""
    kind = (section.kinds or ("grasp",))[0]
    curve: dict[str, dict[int, list[float]]] = {}
    for rows in ctx.outcomes.summaries.values():
        for r in rows:
            if r["kind"] != kind or r["split"] != "seen":
                continue
            method, _, step = str(r["method"]).partition("@")
            curve.setdefault(method, {}).setdefault(int(step) if step else -1, []).append(r["position_cm_median"])
    if not any(len(v) > 1 for v in curve.values()):
        return []
    minutes = {e["name"]: {int(k): v for k, v in (e.get("minutes_at_steps") or {}).items()}
               for e in ctx.outcomes.entries}
    steps = sorted({s for v in curve.values() for s in v if s >= 0})
    lines = ["| method | " + " | ".join(f"step {s}" for s in steps) + " | final |", "|---" * (len(steps) + 2) + "|"]
    for method, by_step in sorted(curve.items()):
        at = minutes.get(method, {})
        cells = [(f"{sum(by_step[s]) / len(by_step[s]):.1f}" + (f" ({at[s]:.0f} min)" if s in at else ""))
                 if s in by_step else "–" for s in steps]
        final = by_step.get(-1)
        cells.append(f"{sum(final) / len(final):.1f}" if final else "–")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
