"""Offline keyframe accuracy: how close is each policy's first keyframe to the scripted expert's?

For every evaluation scene (the same seeds as ``abm eval``), the policy predicts a keyframe from the
first observation and is compared with the expert's first keyframe (the approach above the target
object): position error in cm, rotation error in degrees, gripper state agreement. It isolates the
question the paper asks — does the policy find the *target object*, for seen and for unseen objects —
from the rest of the rollout, which short CPU training cannot yet complete.

Usage: python benchmarks/keyframe_accuracy.py --run RUN [--run RUN2 ...] --tasks pick_block place_food
           [--splits seen unseen] [--episodes 10]
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

from abm.evaluation.results import eval_seed
from abm.evaluation.runner import method_labels
from abm.geometry import quat_angle_deg
from abm.machine import describe_machine
from abm.policy.inference import Policy
from abm.sim.env import make_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, type=Path)
    parser.add_argument("--tasks", nargs="+", required=True)
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen"])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=128)
    args = parser.parse_args()

    labels = method_labels(args.run)
    policies = {labels[str(r)]: Policy.load(r) for r in args.run}
    errors: dict[tuple[str, str, str], list[tuple[float, float, bool]]] = {}
    for task in args.tasks:
        for split in args.splits:
            for ep in range(args.episodes):
                with make_env(task, split, eval_seed(0, ep), args.resolution) as env:
                    obs = env.reset()
                    expert = next(iter(env.expert_actions()))
                    for name, policy in policies.items():
                        act = policy.act(obs, env.instruction, env.object_names)
                        pos = 100 * float(np.linalg.norm(act.position - expert.position))
                        rot = float(quat_angle_deg(act.quaternion, expert.quaternion))
                        errors.setdefault((name, task, split), []).append(
                            (pos, rot, act.gripper_open == expert.gripper_open))
    print(f"machine: {describe_machine()}; {args.episodes} scenes per task and split (seeds as abm eval)")
    print("| method | task | split | position error cm (median) | within 5 cm | rotation error ° (median) "
          "| gripper agrees |")
    print("|---|---|---|---|---|---|---|")
    for (name, task, split), rows in sorted(errors.items(), key=lambda kv: (kv[0][1], kv[0][2], kv[0][0])):
        pos = [r[0] for r in rows]
        print(f"| {name} | {task} | {split} | {statistics.median(pos):.1f} | "
              f"{sum(p < 5 for p in pos)}/{len(pos)} | {statistics.median(r[1] for r in rows):.0f} | "
              f"{sum(r[2] for r in rows)}/{len(rows)} |")


if __name__ == "__main__":
    main()
