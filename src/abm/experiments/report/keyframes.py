"""The keyframe-accuracy diagnosis as a report reads it: medians per keyframe kind and the sentences and tables
that several sections write from them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row

KIND_ORDER = {"approach": 0, "grasp": 1, "lift": 2, "move": 3, "place": 4, "retreat": 5}


def kind_medians(rows: Sequence[Mapping[str, Any]], split: str) -> dict[str, tuple[float, float, float | None]]:
    """Keyframe kind -> (position error cm, rotation error °, a random yaw's error ° or ``None`` when the
    diagnosis predates it), each the median over the tasks of the per-task medians of ``split``."""
    by_kind: dict[str, list[Mapping[str, Any]]] = {}
    for row in rows:
        if row["split"] == split:
            by_kind.setdefault(row["kind"], []).append(row)
    out = {}
    for kind in sorted(by_kind, key=lambda k: (KIND_ORDER.get(k, 9), k)):
        found = by_kind[kind]
        chance = [float(r["yaw_chance_deg"]) for r in found if "yaw_chance_deg" in r]
        out[kind] = (float(np.median([r["position_cm_median"] for r in found])),
                     float(np.median([r["rotation_deg_median"] for r in found])),
                     float(np.median(chance)) if chance else None)
    return out


def weakest_keyframes(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str = "seen") -> str:
    """One sentence per run: its keyframe kinds by median (over tasks) position error, worst first."""
    parts = []
    for run, rows in summaries.items():
        by_kind: dict[str, list[float]] = {}
        for row in rows:
            if row["split"] == split:
                by_kind.setdefault(row["kind"], []).append(row["position_cm_median"])
        if by_kind:
            ranked = sorted(((float(np.median(v)), k) for k, v in by_kind.items() if len(v) > 1), reverse=True)
            parts.append(f"{run}: " + ", ".join(f"{k} {cm:.1f} cm" for cm, k in ranked))
    if not parts:
        return ""
    return (f"Keyframe position error ({split} objects, teacher-forced on the expert's rollouts, median over the "
            "tasks that have the keyframe, worst first): " + "; ".join(parts) + ".")


def approach_yaw(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str = "seen",
                 task: str = "place_food") -> str:
    """One sentence: each run's rotation error where it chooses the yaw (the approach keyframe) against the
    grasp that follows it, median over the tasks, and on ``task``."""
    parts = []
    for run, rows in summaries.items():
        by_kind: dict[str, list[float]] = {}
        at_task: dict[str, float] = {}
        for row in rows:
            if row["split"] == split and row["kind"] in ("approach", "grasp"):
                by_kind.setdefault(row["kind"], []).append(row["rotation_deg_median"])
                if row["task"] == task:
                    at_task[row["kind"]] = row["rotation_deg_median"]
        if "approach" in by_kind and "grasp" in by_kind:
            parts.append(f"{run} {np.median(by_kind['approach']):.0f}° / {np.median(by_kind['grasp']):.0f}°"
                         + (f" ({task} {at_task['approach']:.0f}°)" if "approach" in at_task else ""))
    if not parts:
        return ""
    return (f"Rotation error ({split} objects, symmetry-aware, median over the tasks) at the approach keyframe, "
            "where the policy chooses the yaw from the scene, against the grasp keyframe that follows it from "
            "the approach pose: " + "; ".join(parts) + ".")


def keyframe_table(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str,
                   order: Mapping[str, int]) -> str:
    """Median position error (cm) / rotation error (°, symmetry-aware) per task and keyframe kind, one column
    per diagnosis (tasks in ``order``)."""
    runs = list(summaries)
    rows: dict[tuple[str, str], dict[str, Mapping[str, Any]]] = {}
    for run in runs:
        for row in summaries[run]:
            if row["split"] == split:
                rows.setdefault((row["task"], row["kind"]), {})[run] = row
    lines = table_head(["task", "keyframe", *runs])
    for (task, kind), by_run in sorted(rows.items(), key=lambda kv: (order.get(kv[0][0], 99), kv[0][0])):
        cells = [f"{r['position_cm_median']:.1f} / {r['rotation_deg_median']:.0f}" if (r := by_run.get(run))
                 else "–" for run in runs]
        lines.append(table_row([task, kind, *cells]))
    return "\n".join(lines)


def final_rows(ctx: Context) -> list[Mapping[str, Any]]:
    return [row for rows in ctx.outcomes.summaries.values() for row in rows if "@" not in str(row["method"])]
