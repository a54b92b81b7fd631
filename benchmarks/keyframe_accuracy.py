"""Offline keyframe accuracy of trained policies, per keyframe kind (the quick check before rollouts).

The command line of the ``keyframe_accuracy`` diagnosis (:class:`abm.evaluation.diagnose.keyframe_accuracy.
KeyframeAccuracy`, which the experiment engine runs in its diagnose stage): on evaluation scenes (the seeds of
``abm eval``) the expert is rolled out and each policy predicts at every expert keyframe; position error,
symmetry-aware rotation error and gripper agreement are reported per kind (approach, grasp, lift, move, place, ...).

With ``--steps`` the listed checkpoints of each run are scored too, which gives the grasp-keyframe
error against training time. ``--grounder oracle`` feeds a CLIP-grounded mask policy the simulator's
mask instead of its own: an error that stays is the policy's (what it learned), not the grounder's.

Usage: python benchmarks/keyframe_accuracy.py --run RUN [--run RUN2 ...] --tasks pick_block place_food
           [--splits seen unseen] [--episodes 10] [--steps 500 1000 ...] [--kinds grasp place]
           [--grounder oracle|clip|tracking [--clip-model M]] [--out errors.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli import configure_logging
from abm.evaluation.diagnose.keyframe_accuracy import KeyframeAccuracy
from abm.evaluation.keyframe_accuracy import markdown
from abm.grounding.config import GROUNDERS


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
    parser.add_argument("--grounder", choices=GROUNDERS.names(), default=None,
                        help="override the grounder stored in the checkpoints (as abm eval --grounder)")
    parser.add_argument("--clip-model", default=None, help="CLIP weights of --grounder clip / tracking")
    parser.add_argument("--out", type=Path, default=None, help="write all errors and summaries as JSON")
    args = parser.parse_args()
    configure_logging()
    payload = KeyframeAccuracy(models=tuple(args.run), tasks=tuple(args.tasks), out=args.out,
                               splits=tuple(args.splits), episodes=args.episodes, resolution=args.resolution,
                               steps=tuple(args.steps), grounder=args.grounder, clip_model=args.clip_model).run()
    if args.kinds is not None:
        print(markdown(payload["summary"], args.kinds))
    if args.out is not None:
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
