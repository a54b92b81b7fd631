"""Grounding quality of the destination (the policy's second mask) beside the target's, per task and split.

Usage: python benchmarks/destination_grounding.py [--clip-model models/benchmark-clip] [--episodes 5]
                                                  [--tasks place_wine pick_block ...] [--out results.json]

For the first observation of evaluation scenes (held-out seeds: :func:`abm.evaluation.results.eval_seed`), each
task's target X and its declared destination (``Task.destination``) are grounded by the CLIP grounder (its default
configuration with ``--clip-model``, as the paper-table runs ground), the text as the policy reads it (X from the
instruction's split, the destination from :func:`abm.language.roles.instruction_destination`), and scored
against the simulator's segmentation of the true object (``abm.grounding.metrics``): point IoU, hit rate (mask
centre inside the object's bounding box + 1 cm) and found rate. The oracle grounds both exactly (IoU 1) by
construction. Prints a markdown table; ``--out`` writes the rows as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from abm.evaluation.results import eval_seed
from abm.geometry import Workspace, fuse_cameras
from abm.grounding.config import ClipGrounderConfig, build_grounder
from abm.grounding.grounders import target_point_mask
from abm.grounding.metrics import score_mask
from abm.language.roles import instruction_destination, split_instruction
from abm.sim.env import make_env
from abm.sim.tasks import TASKS

TASKS_MEASURED = ("pick_block", "place_food", "place_wine", "put_in_shelf", "water_plants", "close_jar", "insert_peg",
                  "put_in_container")


def iou(xyz: np.ndarray, mask: np.ndarray, truth: np.ndarray) -> float:
    """Point IoU of a mask (values > 0.5) and the true points (NaN when both are empty)."""
    sel, tgt = np.asarray(mask).reshape(-1) > 0.5, np.asarray(truth, bool).reshape(-1)
    union = int((sel | tgt).sum())
    return int((sel & tgt).sum()) / union if union else math.nan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip-model", default="models/benchmark-clip")
    parser.add_argument("--episodes", type=int, default=5, help="evaluation scenes per task and split")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS_MEASURED))
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen"])
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    grounder = build_grounder(ClipGrounderConfig(model=args.clip_model, device="cpu"))
    rows: dict[tuple[str, str, str], list[tuple[float, bool, bool]]] = defaultdict(list)
    workspace = Workspace()
    for task in args.tasks:
        for split in args.splits:
            for episode in range(args.episodes):
                with make_env(task, split, eval_seed(0, episode), args.resolution) as env:
                    obs = env.reset()
                    names, truth_names, instruction = env.object_names, env.target_names, env.instruction
                cloud = fuse_cameras(obs, workspace)
                x = split_instruction(instruction, names)[0]
                queries = {"target": (x, truth_names[0]),
                           "destination": (instruction_destination(instruction),
                                           TASKS[task].destination_name(truth_names))}
                for role, (text, true_name) in queries.items():
                    if text is None or true_name is None:
                        continue
                    truth = target_point_mask(obs, cloud, true_name, names)
                    field = grounder.ground(obs, cloud, text, names)
                    score = score_mask(cloud.xyz, field.mask, truth, field.found)
                    rows[(task, split, role)].append((iou(cloud.xyz, field.mask, truth), score.hit, score.found))
    table: list[dict[str, Any]] = []
    print(f"CLIP {args.clip_model}, {args.episodes} evaluation scenes per task and split (first observation)")
    print("| task | split | object | n | IoU | hit rate | found rate |")
    print("|---|---|---|---|---|---|---|")
    for (task, split, role), items in rows.items():
        ious = [v for v, _, _ in items if not math.isnan(v)]
        row = {"task": task, "split": split, "object": role, "n": len(items),
               "iou": float(np.mean(ious)) if ious else math.nan,
               "hit_rate": float(np.mean([h for _, h, _ in items])),
               "found_rate": float(np.mean([f for _, _, f in items]))}
        table.append(row)
        print(f"| {task} | {split} | {role} | {row['n']} | {row['iou']:.2f} | {row['hit_rate']:.2f} | "
              f"{row['found_rate']:.2f} |")
    if args.out:
        Path(args.out).write_text(json.dumps(table, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
