"""Why rollouts stop: trace a policy's closed-loop keyframes against the expert's, per keyframe kind.

Rolls every checkpoint out on the evaluation scenes of ``abm eval`` (repeat 0) and, per step, records the
motion's status (reached / blocked / unreachable / collided), how far the arm stopped from the predicted
pose, and the prediction's distance and height offset from the expert's keyframe of the same index
(:mod:`abm.evaluation.motion_trace`). The table says at which keyframe kind motions are blocked and whether
the blocked targets are far from the expert's (a wrong place) or just below it (pressing into something).

Usage: python benchmarks/motion_failures.py --run CKPT [--run CKPT2 ...] --tasks place_food take_off_pan
           [--split seen] [--episodes 10] [--out traces.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from abm.evaluation.motion_trace import as_records, markdown, summarise_traces, trace_rollout
from abm.evaluation.policies import rollout_state
from abm.evaluation.results import eval_seed
from abm.evaluation.runner import method_labels
from abm.machine import describe_machine
from abm.policy import KeyframePolicy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, type=Path)
    parser.add_argument("--tasks", nargs="+", required=True)
    parser.add_argument("--split", default="seen")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=None, help="write every step's trace and the summaries")
    args = parser.parse_args()

    labels = method_labels(args.run)
    start = time.perf_counter()
    report: dict[str, object] = {"machine": describe_machine(), "split": args.split, "episodes": args.episodes,
                                 "methods": {}}
    for run in args.run:
        name = labels[str(run)]
        for task in args.tasks:
            traces = []
            for episode in range(args.episodes):
                seed = eval_seed(0, episode)
                with rollout_state(seed):  # the RNG state abm eval gives this scene
                    policy = KeyframePolicy.from_checkpoint(run)
                    policy.reset()
                    traces += trace_rollout(policy.act, task, args.split, seed)
            rows = summarise_traces(traces)
            wins = sum(t.success for t in traces)
            print(f"\n{name} · {task} · {args.split}: {wins}/{args.episodes} successes")
            print(markdown(rows))
            report["methods"].setdefault(name, {})[task] = {  # type: ignore[union-attr]
                "successes": wins, "summary": rows, "steps": as_records(traces)}
    print(f"\nmachine: {describe_machine()}; {time.perf_counter() - start:.0f} s")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
