"""The zoom probe's tables (docs/results/zoom_probe.md) from its JSON (docs/results/zoom_probe.json:
``{"fit": [...], "accuracy": [...], "rollouts": [...]}``, filled by ``benchmarks/rotation_fit.py --probe`` and
``benchmarks/probe_record.py``): the yaw fit per step and arm, and the keyframe accuracy and rollouts of every arm at
one step."""

from __future__ import annotations

from typing import Any

FIT_KINDS = ("all", "approach", "grasp", "move", "place")


def markdown_tables(probe: dict[str, Any], step: int) -> str:
    """The fit table (every step and arm, augmentation on, over both tasks), and the keyframe accuracy (median yaw °
    / position cm) and rollout tables of every arm at ``step``."""
    order = ("single-stage", "two-stage", "single-stage+crop", "two-stage+crop")
    arms = sorted(dict.fromkeys(r["arm"] for r in probe["fit"]), key=lambda a: (a not in order, order.index(a)
                                                                               if a in order else 0, a))
    out = ["| step | arm | " + " | ".join("all keyframes" if k == "all" else k for k in FIT_KINDS) + " |",
           "|---|---|" + "---|" * len(FIT_KINDS)]
    for s in sorted({r["step"] for r in probe["fit"]}):
        for arm in arms:
            ce = {r["keyframe"]: r["yaw_ce"] for r in probe["fit"]
                  if r["arm"] == arm and r["step"] == s and r["augment"] and r["task"] == "all"}
            if ce:
                out.append(f"| {s} | {arm} | " + " | ".join(f"{ce[k]:.2f}" for k in FIT_KINDS) + " |")
    acc = {(r["arm"], r["task"], r["split"], r["keyframe"]): r for r in probe["accuracy"] if r["step"] == step}
    ro = {(r["arm"], r["task"], r["split"]): r for r in probe["rollouts"] if r["step"] == step}
    tasks = list(dict.fromkeys(r["task"] for r in probe["rollouts"]))
    head = " | ".join(f"{a} ({step})" for a in arms)
    out += ["", f"| task | split | keyframe | {head} |", "|---|---|---|" + "---|" * len(arms)]
    for task in tasks:
        for split in ("seen", "unseen"):
            for kind in ("approach", "grasp", "move", "place"):
                found = [acc.get((a, task, split, kind)) for a in arms]
                cells = [f"{r['yaw_error_deg']:.0f} / {r['position_error_cm']:.1f}" if r else "–" for r in found]
                out.append(f"| {task} | {split} | {kind} | " + " | ".join(cells) + " |")
    out += ["", f"| task | split | {head} |", "|---|---|" + "---|" * len(arms)]
    for split in ("seen", "unseen"):
        for task in tasks:
            out.append(f"| {task} | {split} | " + " | ".join(
                str(ro[(a, task, split)]["successes"]) if (a, task, split) in ro else "–" for a in arms) + " |")
    averages = []
    for a in arms:
        parts = []
        for split in ("seen", "unseen"):
            rows = [ro[(a, t, split)] for t in tasks if (a, t, split) in ro]
            parts.append(f"{100 * sum(r['successes'] for r in rows) / sum(r['episodes'] for r in rows):.0f}"
                         if rows else "–")
        averages.append(" / ".join(parts))
    out.append("| **average %** | seen / unseen | " + " | ".join(averages) + " |")
    return "\n".join(out)
