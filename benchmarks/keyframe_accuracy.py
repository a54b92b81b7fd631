"""Offline keyframe accuracy of trained policies, per keyframe kind (the quick check before rollouts).

On evaluation scenes (the seeds of ``abm eval``) the expert is rolled out and each policy predicts at
every expert keyframe; position error, symmetry-aware rotation error and gripper agreement are
reported per kind (approach, grasp, lift, move, place, ...). See
:mod:`abm.evaluation.keyframe_accuracy`.

With ``--steps`` the listed checkpoints of each run are scored too, which gives the grasp-keyframe
error against training time. ``--grounder oracle`` feeds a CLIP-grounded mask policy the simulator's
mask instead of its own: an error that stays is the policy's (what it learned), not the grounder's.

Usage: python benchmarks/keyframe_accuracy.py --run RUN [--run RUN2 ...] --tasks pick_block place_food
           [--splits seen unseen] [--episodes 10] [--steps 500 1000 ...] [--kinds grasp place]
           [--grounder oracle|clip|tracking [--clip-model M]] [--out errors.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from abm.evaluation.keyframe_accuracy import as_records, keyframe_errors, markdown, summarise
from abm.evaluation.runner import method_labels
from abm.grounding.config import grounder_from_flags
from abm.machine import describe_machine
from abm.policy import KeyframePolicy
from abm.policy.checkpoint import checkpoint_path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, type=Path)
    parser.add_argument("--tasks", nargs="+", required=True)
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen"])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=128, help="camera pixels (as in training)")
    parser.add_argument("--steps", type=int, nargs="*", default=[],
                        help="also score these checkpoint steps of every run (default: latest only)")
    parser.add_argument("--kinds", nargs="*", default=None, help="only print these keyframe kinds")
    parser.add_argument("--grounder", choices=["clip", "oracle", "tracking"], default=None,
                        help="override the grounder stored in the checkpoints (as abm eval --grounder)")
    parser.add_argument("--clip-model", default=None, help="CLIP weights of --grounder clip / tracking")
    parser.add_argument("--out", type=Path, default=None, help="write all errors and summaries as JSON")
    args = parser.parse_args()

    grounder = grounder_from_flags(args.grounder, args.clip_model)
    labels = method_labels(args.run)
    policies = {}
    for run in args.run:
        name = labels[str(run)] + (f" [{args.grounder} grounder]" if args.grounder else "")
        policies[name] = KeyframePolicy.from_checkpoint(run, grounder=grounder)
        for step in args.steps:
            path = checkpoint_path(run, step)
            if path.is_file():
                policies[f"{name}@{step}"] = KeyframePolicy.from_checkpoint(path, grounder=grounder)
            else:
                print(f"skipping {path}: no such checkpoint")
    start = time.perf_counter()
    errors = []
    for task in args.tasks:
        for split in args.splits:
            errors += keyframe_errors({k: p.act for k, p in policies.items()}, task, split, args.episodes,
                                      args.resolution)
    rows = summarise(errors)
    print(f"machine: {describe_machine()}; {args.episodes} scenes per task and split (seeds as abm eval); "
          f"{time.perf_counter() - start:.0f} s")
    print(markdown(rows, args.kinds))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({
            "machine": describe_machine(), "episodes": args.episodes, "grounder": args.grounder or "checkpoint's",
            "checkpoints": {k: str(p.checkpoint_path) for k, p in policies.items()},
            "summary": rows, "errors": as_records(errors)}, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
