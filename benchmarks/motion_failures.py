"""Why rollouts stop: trace a policy's closed-loop keyframes against the expert's, per keyframe kind.

The command line of the ``failure_reasons`` diagnosis (:class:`abm.evaluation.diagnose.failure_reasons.
FailureReasons`): rolls every checkpoint out on the evaluation scenes of ``abm eval`` (repeat 0) and, per step,
records the motion's status (reached / blocked / unreachable / collided), how far the arm stopped from the predicted
pose, and the prediction's distance and height offset from the expert's keyframe of the same index
(:mod:`abm.evaluation.motion_trace`). The table says at which keyframe kind motions are blocked and whether the
blocked targets are far from the expert's (a wrong place) or just below it (pressing into something).

Usage: python benchmarks/motion_failures.py --run CKPT [--run CKPT2 ...] --tasks place_food take_off_pan
           [--split seen] [--episodes 10] [--out traces.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli import configure_logging
from abm.evaluation.diagnose.failure_reasons import FailureReasons


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, type=Path)
    parser.add_argument("--tasks", nargs="+", required=True)
    parser.add_argument("--split", default="seen")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=None, help="write every step's trace and the summaries")
    args = parser.parse_args()
    configure_logging()
    FailureReasons(models=tuple(args.run), tasks=tuple(args.tasks), out=args.out, split=args.split,
                   episodes=args.episodes).run()
    if args.out is not None:
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
