"""A probe's records per arm (``report.arm_records``, e.g. ``docs/results/destination_probe.json``; issue 53):
keyframe accuracy, rollouts and grasp <-> lift loops of every arm (run or evaluation variant) of a spec.

The file is one JSON object::

    {"accuracy": [{arm, task, split, keyframe, yaw_error_deg, position_error_cm}],
     "rollouts": [{arm, task, split, successes, episodes}],
     "loops":    [{arm, task, split, loops, episodes}]}

``accuracy`` holds the diagnosis's (teacher-forced keyframe accuracy) medians over the evaluation scenes of each
task, split and keyframe kind: ``position_error_cm`` the median position error, ``yaw_error_deg`` the median
rotation error, symmetry-aware (every keyframe of the benchmark's tasks is top-down, so it is the error of the
yaw); arms without a diagnosis (an evaluation variant) have none. ``rollouts`` holds every evaluated cell.

An episode *loops* (:func:`loops`) when its per-step records (``abm eval``'s ``step_records``) show the pick-up
repeated: the kinds of the expert keyframes nearest each step (``expert``), with ``approach`` steps and steps
without an expert keyframe left out, every destination kind (``move``, ``place``, ``retreat``, ``pour``) kept as a
break and repeats of one kind merged, hold ``grasp, lift, grasp`` or ``lift, grasp, lift`` in a row: a grasp
and a lift at the pick-up spot, then the other again, without a move (or any step at the destination) between.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from abm.evaluation.results import OUTCOME_ARCHIVE, read_outcome_archive
from abm.experiments.spec import ExperimentSpec
from abm.experiments.state import Layout

PICK_UP = ("grasp", "lift")
"""Expert keyframe kinds at the pick-up spot whose repetition is a loop."""
SKIPPED = ("approach", "")
"""Kinds left out of the loop sequence (above the pick-up spot; no expert keyframe)."""
LOOPS = (("grasp", "lift", "grasp"), ("lift", "grasp", "lift"))
"""Runs of merged kinds that make a loop."""

Loops = dict[tuple[str, str, str], tuple[int, int]]  #: (arm, task, split) -> (episodes that loop, episodes)


def loops(step_records: Sequence[Mapping[str, Any]]) -> bool:
    """Whether an episode's step records show a grasp <-> lift loop (the module doc's rule)."""
    merged: list[str] = []
    for record in step_records:
        kind = str(record.get("expert", ""))
        if kind in SKIPPED:
            continue
        kind = kind if kind in PICK_UP else "destination"
        if not merged or merged[-1] != kind:
            merged.append(kind)
    return any(tuple(merged[i:i + 3]) in LOOPS for i in range(len(merged) - 2))


def arms(spec: ExperimentSpec) -> list[str]:
    """Every arm of the spec: its runs, then its evaluation variants, in spec order."""
    return [*spec.runs, *(v.name for v in spec.evaluation.variants)]


def loop_counts(spec: ExperimentSpec, layout: Layout) -> Loops:
    """``(arm, task, split) -> (episodes that loop, episodes)`` from every finished evaluation's outcome archive
    under OUT (``OUT/eval/ARM/SPLIT/outcomes.jsonl.xz``, restored from the kept folder on a fresh clone)."""
    counts: Loops = {}
    for arm in arms(spec):
        for split in spec.evaluation.splits:
            path = layout.eval_dir(arm, split.split) / OUTCOME_ARCHIVE
            if not path.is_file():
                continue
            for outcome in read_outcome_archive(path):
                key = (arm, outcome.task, outcome.split)
                looped, episodes = counts.get(key, (0, 0))
                counts[key] = (looped + loops(outcome.step_records), episodes + 1)
    return counts


def loop_share(counts: Loops, arm: str, split: str | None = None) -> float | None:
    """Percentage of ``arm``'s episodes (on ``split``; default every split) that loop, ``None`` before any."""
    found = [v for (name, _, s), v in counts.items() if name == arm and split in (None, s)]
    episodes = sum(n for _, n in found)
    return 100.0 * sum(k for k, _ in found) / episodes if episodes else None


def arm_records(spec: ExperimentSpec, cells: Mapping[tuple[str, str, str], Mapping[str, Any]],
                summaries: Mapping[str, Sequence[Mapping[str, Any]]], counts: Loops) -> dict[str, list[dict[str, Any]]]:
    """The records (module doc) of ``cells`` (``(arm, task, split) -> abm eval's rate``), ``summaries`` (the
    diagnosis's summary rows per arm) and ``counts`` (:func:`loop_counts`), in spec order of the arms."""
    order = {arm: i for i, arm in enumerate(arms(spec))}
    accuracy = [{"arm": arm, "task": row["task"], "split": row["split"], "keyframe": row["kind"],
                 "yaw_error_deg": round(float(row["rotation_deg_median"]), 2),
                 "position_error_cm": round(float(row["position_cm_median"]), 2)}
                for arm in sorted(summaries, key=lambda a: order.get(a, len(order))) if arm in order
                for row in summaries[arm]]
    rollouts = [{"arm": arm, "task": task, "split": split, "successes": round(float(rate["mean"]) *
                 int(rate["episodes"]) / 100), "episodes": int(rate["episodes"])}
                for (arm, task, split), rate in sorted(cells.items(), key=lambda kv: (order.get(kv[0][0], 99), kv[0]))
                if arm in order]
    looped = [{"arm": arm, "task": task, "split": split, "loops": n, "episodes": total}
              for (arm, task, split), (n, total) in sorted(counts.items(), key=lambda kv: (order.get(kv[0][0], 99),
                                                                                            kv[0]))]
    return {"accuracy": accuracy, "rollouts": rollouts, "loops": looped}


def is_arm_records(text: str) -> bool:
    """Whether ``text`` is a file :func:`arm_records` wrote (a JSON object with ``accuracy`` and ``rollouts``)."""
    import json

    try:
        data = json.loads(text)
    except ValueError:
        return False
    return isinstance(data, dict) and {"accuracy", "rollouts"} <= set(data)
