"""The ``probe_accuracy`` report section: a probe's keyframe accuracy on evaluation scenes, a column per arm at its
final step (:mod:`abm.experiments.report.probe`)."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.report.probe import arms, final_step, probe_records
from abm.experiments.spec import Section

SHOWN_KEYFRAME_KINDS = ("approach", "grasp", "move", "place")  #: the keyframe kinds shown, in order


def write(ctx: Context, section: Section) -> list[str]:
    """Median yaw error (°) / median position error (cm) per task, split and keyframe kind ("–": not measured)."""
    step, names = final_step(ctx), arms(ctx, section)
    rows = {(r["arm"], r["task"], r["split"], r["keyframe"]): r for r in probe_records(ctx, section, "accuracy")
            if r["step"] == step}
    if not rows:
        return []
    lines = table_head(["task", "split", "keyframe", *(f"{a} ({step})" for a in names)])
    for task in dict.fromkeys(task for _, task, _, _ in rows):
        for split in ("seen", "unseen"):
            for kind in SHOWN_KEYFRAME_KINDS:
                found = [rows.get((a, task, split, kind)) for a in names]
                lines.append(table_row([task, split, kind, *(
                    f"{r['yaw_error_deg']:.0f} / {r['position_error_cm']:.1f}" if r else "–" for r in found)]))
    return [section.title, "\n".join(lines)]
