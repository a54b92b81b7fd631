"""How much success the policy's action coding alone costs, per task: the scripted expert's keyframes replayed
through encode -> ideal heatmaps / one-hot bins -> decode -> executor, against the expert itself.

A task that stays near 0 % for every trained method is first checked here (issue 25, part 8): when the
replayed expert already fails, the cause is the action representation (view resolution, workspace cube,
rotation bins, the executor), not learning. Per task and split it reports the expert's success, the replayed
success, and the translation / rotation error that coding introduced (median over keyframes).

    python benchmarks/action_replay.py --episodes 10 --resolution 64 [--workspace-size 1.0]
        [--workspace-center 0.5 0 0.35] [--tasks ...] [--json out.json]

The replay is open loop: the same scene seed, the decoded keyframes in order (so it also shows whether the
expert's keyframes suffice without feedback).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from abm.geometry import Workspace, quat_to_bins
from abm.machine import describe_machine
from abm.policy.heads import decode_output, logits_from_targets
from abm.render import OrthographicRenderer
from abm.sim.env import make_env, run_expert, run_policy
from abm.types import KeyframeAction

PAPER_TASKS = ("close_jar", "insert_peg", "pick_block", "place_food", "place_wine", "put_in_shelf", "take_off_pan",
               "water_plants")


def coded(actions: list[KeyframeAction], renderer: OrthographicRenderer, bins: int) -> list[KeyframeAction]:
    """The actions after the policy's encode -> decode round trip (ideal logits of their own targets)."""
    pos = torch.tensor(np.stack([a.position for a in actions]), dtype=torch.float32)
    rot = torch.as_tensor(np.asarray([quat_to_bins(a.quaternion, bins) for a in actions], np.int64).reshape(-1, 3))
    grip = [int(a.gripper_open) for a in actions]
    coll = [int(a.ignore_collision) for a in actions]
    out = logits_from_targets(pos, rot, grip, coll, renderer, num_bins=bins)
    return decode_output(out, renderer)


def angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    d = abs(float(np.dot(q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2))))
    return float(np.degrees(2 * np.arccos(min(d, 1.0))))


def replay(task: str, split: str, seed: int, renderer: OrthographicRenderer, bins: int) -> dict:
    with make_env(task, split, seed, resolution=32) as env:
        expert = run_expert(env)
        actions = [a for _, a in expert.steps]
        if not actions:
            return {"expert": False, "replayed": False, "position_cm": [], "rotation_deg": []}
        decoded = coded(actions, renderer, bins)
        queue = list(decoded)

        def act(_obs):
            return queue.pop(0) if queue else decoded[-1]

        replayed = run_policy(env, act, max_steps=len(decoded))
    pairs = list(zip(actions, decoded, strict=True))
    return {"expert": bool(expert.success), "replayed": bool(replayed.success),
            "position_cm": [100 * float(np.linalg.norm(a.position - d.position)) for a, d in pairs],
            "rotation_deg": [angle_deg(a.quaternion, d.quaternion) for a, d in pairs]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=list(PAPER_TASKS), help="tasks (default: the 8 paper tasks)")
    p.add_argument("--splits", nargs="+", default=["seen"], help="object splits (default seen)")
    p.add_argument("--episodes", type=int, default=10, help="scene seeds per task and split (default 10)")
    p.add_argument("--resolution", type=int, default=64, help="virtual view side in pixels (default 64)")
    p.add_argument("--workspace-size", type=float, default=1.0, help="workspace cube edge in m (default 1.0)")
    p.add_argument("--workspace-center", type=float, nargs=3, default=[0.5, 0.0, 0.35],
                   help="workspace cube centre in m (default 0.5 0 0.35)")
    p.add_argument("--rotation-bins", type=int, default=72, help="bins per Euler angle (default 72: 5 degrees)")
    p.add_argument("--json", default=None, help="write the per-task rows here")
    args = p.parse_args()
    renderer = OrthographicRenderer(Workspace(tuple(args.workspace_center), args.workspace_size), args.resolution)
    rows = []
    print(f"# machine: {describe_machine()}; views {args.resolution}² over a {args.workspace_size} m cube")
    print("| task | split | expert | replayed | position error cm (median) | rotation error ° (median) | s |")
    print("|---|---|---|---|---|---|---|")
    for task in args.tasks:
        for split in args.splits:
            start = time.perf_counter()
            runs = [replay(task, split, seed, renderer, args.rotation_bins) for seed in range(args.episodes)]
            pos = [v for r in runs for v in r["position_cm"]]
            rot = [v for r in runs for v in r["rotation_deg"]]
            row = {"task": task, "split": split, "episodes": len(runs),
                   "expert_successes": sum(r["expert"] for r in runs),
                   "replayed_successes": sum(r["replayed"] for r in runs),
                   "position_cm_median": float(np.median(pos)) if pos else None,
                   "rotation_deg_median": float(np.median(rot)) if rot else None,
                   "seconds": round(time.perf_counter() - start, 1)}
            rows.append(row)
            print(f"| {task} | {split} | {row['expert_successes']}/{len(runs)} | {row['replayed_successes']}/"
                  f"{len(runs)} | {row['position_cm_median']:.2f} | {row['rotation_deg_median']:.1f} | "
                  f"{row['seconds']} |", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": describe_machine(), "args": vars(args), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
