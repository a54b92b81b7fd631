"""The grounding-quality report sections: ``grounding_quality`` (mask quality of one grounding configuration on the
evaluated tasks, from ``benchmarks/grounding_quality.py``'s records) and ``destination_grounding`` (the spec's CLIP
grounder on each task's target and destination, from the diagnose stage's ``destination_grounding`` diagnosis)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import table_head, table_row
from abm.experiments.spec import Section


def quality_cells(row: Mapping[str, Any] | None) -> list[str]:
    """A row's mask IoU and hit rate as a table shows them (``0.98``, ``100 %``; – when there is no row, or no
    IoU: neither mask had a point)."""
    if row is None:
        return ["–", "–"]
    iou = "–" if math.isnan(row["iou"]) else f"{row['iou']:.2f}"
    return [iou, f"{100 * row['hit_rate']:.0f} %"]


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
                lines.append(table_row([t, s, str(r["n"]), *quality_cells(r), f"{100 * r['top1']:.0f} %"]))
    return [section.title.format(config=section.config), "\n".join(lines)]


def write_destination(ctx: Context, section: Section) -> list[str]:
    """The destination's grounding quality beside the target's, per task (the spec's task order) and split: mask
    IoU and hit rate of each (the rows of the ``destination_grounding`` diagnosis; nothing before it ran)."""
    rows = ctx.outcomes.destination_grounding
    if not rows:
        return []
    found = {(r["task"], r["split"], r["object"]): r for r in rows}
    order = ctx.task_order()
    tasks = sorted(dict.fromkeys(r["task"] for r in rows), key=lambda t: order.get(t, len(order)))
    lines = table_head(["task", "split", "scenes", "target IoU", "target hit rate", "destination IoU",
                        "destination hit rate"])
    for task in tasks:
        for split in dict.fromkeys(r["split"] for r in rows):
            target, destination = found.get((task, split, "target")), found.get((task, split, "destination"))
            if target is None and destination is None:
                continue
            scenes = (target or destination or {})["n"]
            # a task without a destination is no cell left to evaluate: "none", not the report's "–"
            lines.append(table_row([task, split, str(scenes), *quality_cells(target),
                                    *(quality_cells(destination) if destination is not None else ["none", "none"])]))
    kept = ctx.layout.show(ctx.layout.kept / ctx.layout.destination_grounding.name)
    note = (f"The benchmark CLIP (`{ctx.spec.clip}`) grounder in its default configuration, on the first observation "
            "of each evaluation scene (held-out seeds); IoU: the mask's points against the simulator's segmentation "
            "of the true object; hit: the mask's centre inside the object's box grown by 1 cm; none: the task names no "
            f"destination; –: no IoU (neither mask had a point). JSON: `{kept}`.")
    return [section.title, "\n".join(lines), note]
