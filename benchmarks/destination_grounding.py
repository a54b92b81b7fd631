"""Grounding quality of the destination (the policy's second mask) beside the target's, per task and split.

The command line of the ``destination_grounding`` diagnosis
(:class:`abm.evaluation.diagnose.destination_grounding.DestinationGrounding`, which the experiment engine runs once
per spec, for its CLIP, in the diagnose stage of a spec whose ``diagnose:`` block has ``destination_grounding:``,
e.g. ``configs/experiments/paper_tables_v3.yaml``). For the first observation of evaluation scenes (held-out
seeds), each task's target X and its declared destination are grounded by the CLIP grounder (its default
configuration with ``--clip-model``, as the paper-table runs ground) and scored against the simulator's
segmentation of the true object: point IoU, hit rate (mask centre inside the object's bounding box + 1 cm) and
found rate. The oracle grounds both exactly (IoU 1) by construction. Prints a markdown table; ``--out`` writes
the rows as JSON (the format of docs/results/destination_grounding.json).

Usage: python benchmarks/destination_grounding.py [--clip-model models/benchmark-clip] [--episodes 5]
                                                  [--tasks place_wine pick_block ...] [--out results.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.evaluation.diagnose.destination_grounding import DESTINATION_TASKS, DestinationGrounding, markdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip-model", default="models/benchmark-clip")
    parser.add_argument("--episodes", type=int, default=5, help="evaluation scenes per task and split")
    parser.add_argument("--tasks", nargs="+", default=list(DESTINATION_TASKS))
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen"])
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = DestinationGrounding(clip_model=args.clip_model, out=args.out, tasks=tuple(args.tasks),
                                splits=tuple(args.splits), episodes=args.episodes, resolution=args.resolution).run()
    print(f"CLIP {args.clip_model}, {args.episodes} evaluation scenes per task and split (first observation)")
    print(markdown(rows))


if __name__ == "__main__":
    main()
