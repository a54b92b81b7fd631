"""The ``probe_rollouts`` report section: a probe's rollout successes, a column per arm at its final step, with
each arm's seen / unseen average (:mod:`abm.experiments.report.probe`)."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.report.probe import arms, final_step, probe_records
from abm.experiments.spec import Section

PROBE_SPLITS = ("seen", "unseen")


def write(ctx: Context, section: Section) -> list[str]:
    """Successes per task and split ("–": not rolled out), then the average success (%) over the tasks' episodes,
    seen / unseen."""
    step, names = final_step(ctx), arms(ctx, section)
    rows = {(r["arm"], r["task"], r["split"]): r for r in probe_records(ctx, section, "rollouts") if r["step"] == step}
    if not rows:
        return []
    tasks = list(dict.fromkeys(task for _, task, _ in rows))
    lines = table_head(["task", "split", *(f"{a} ({step})" for a in names)])
    for split in PROBE_SPLITS:
        for task in tasks:
            lines.append(table_row([task, split, *(
                str(rows[(a, task, split)]["successes"]) if (a, task, split) in rows else "–" for a in names)]))
    averages = []
    for arm in names:
        parts = []
        for split in PROBE_SPLITS:
            found = [rows[(arm, t, split)] for t in tasks if (arm, t, split) in rows]
            parts.append(f"{100 * sum(r['successes'] for r in found) / sum(r['episodes'] for r in found):.0f}"
                         if found else "–")
        averages.append(" / ".join(parts))
    lines.append(table_row(["**average %**", "seen / unseen", *averages]))
    return [section.title, "\n".join(lines)]
