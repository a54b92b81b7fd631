"""Tracked vs per-step grounding on ABM-Bench expert rollouts: mask IoU at every keyframe and time per step.

The expert's observations of every trainable task are grounded at each keyframe in two ways: per step
(the grounder runs every time, as in the paper) and tracked (:class:`abm.grounding.tracking.TrackingGrounder`
around the same grounder). IoU is measured against the simulator's segmentation of the target.

Without real CLIP weights the grounder is the oracle plus noise that imitates CLIP's failure modes:
every call drops a share of the target's points (``--drop``) and, with probability ``--jump``, answers
with another object of the scene (the target "moving between steps" the paper describes). With
``--clip-model DIR`` the real CLIP grounder is measured instead.

    python benchmarks/tracking_iou.py --seeds 3 --jump 0.25 --drop 0.2
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import numpy as np

from abm.data.generate import trainable_tasks
from abm.geometry import Workspace, fuse_cameras
from abm.grounding import build_grounder
from abm.grounding.grounders import OracleGrounder
from abm.grounding.mask_field import MaskField
from abm.grounding.tracking import TrackingGrounder
from abm.machine import describe_machine
from abm.sim.env import TaskEnv, run_expert


class NoisyOracle:
    """The oracle with CLIP-like errors: dropped target points and, sometimes, another object."""

    name = "noisy-oracle"

    def __init__(self, drop: float, jump: float, seed: int) -> None:
        self.oracle, self.drop, self.jump = OracleGrounder(), drop, jump
        self.rng = np.random.default_rng(seed)

    def ground(self, observation, cloud, target, object_names=None) -> MaskField:
        name = target
        if self.rng.random() < self.jump:
            others = [n for n in object_names.values() if n != target]
            name = str(self.rng.choice(others)) if others else target
        mask = self.oracle.ground(observation, cloud, name, object_names).mask.copy()
        mask[self.rng.random(len(mask)) < self.drop] = 0.0
        return MaskField(mask, mask.copy(), bool(mask.any()), target, "")


def expert_episode(task: str, split: str, seed: int, resolution: int, folder: str | None):
    """The expert rollout of one scene, read from / written to ``folder`` when given."""
    from pathlib import Path

    from abm.data.episode_store import load_episode, save_episode

    path = Path(folder) / f"{task}_{split}_{seed}_{resolution}.h5" if folder else None
    if path is not None and path.is_file():
        return load_episode(path)
    with TaskEnv(task, split, seed, resolution=resolution) as env:
        episode = run_expert(env)
    if path is not None:
        save_episode(episode, path)
    return episode


def iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a > 0.5, b > 0.5
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=trainable_tasks())
    p.add_argument("--split", default="seen")
    p.add_argument("--seeds", type=int, default=3, help="expert episodes per task")
    p.add_argument("--resolution", type=int, default=128, help="camera pixels")
    p.add_argument("--drop", type=float, default=0.2, help="share of target points the noisy oracle drops")
    p.add_argument("--jump", type=float, default=0.25, help="probability that it answers another object")
    p.add_argument("--clip-model", default=None, help="measure the CLIP grounder with these weights instead")
    p.add_argument("--clip-options", default="{}",
                   help='JSON options of the CLIP grounder, e.g. \'{"mode": "proposals"}\' (default: package default)')
    p.add_argument("--reacquire", choices=("on", "off"), default="off",
                   help="tracking re-acquires when the tracked target's score falls (default off)")
    p.add_argument("--out", default=None, help="write the per-task summary as JSON")
    p.add_argument("--episodes", default=None,
                   help="folder keeping the expert episodes (task_split_seed.h5): reused by later runs")
    args = p.parse_args()

    clip_options = json.loads(args.clip_options)
    ws = Workspace()
    truth = OracleGrounder()
    stats: dict[tuple[str, str], list] = defaultdict(list)
    seconds: dict[str, list[float]] = defaultdict(list)
    inner_calls: dict[str, list[int]] = defaultdict(list)
    for task in args.tasks:
        for seed in range(args.seeds):
            episode = expert_episode(task, args.split, seed, args.resolution, args.episodes)
            target, names = episode.target_names[0], episode.object_names

            def make(seed=seed):
                if args.clip_model:
                    return build_grounder({"kind": "clip", "model": args.clip_model, **clip_options})
                return NoisyOracle(args.drop, args.jump, seed)

            reacquire = args.reacquire == "on"
            per_step, tracked = make(), TrackingGrounder(make(), reacquire=reacquire)
            for obs, _ in episode.steps:
                cloud = fuse_cameras(obs, ws)
                want = truth.ground(obs, cloud, target, names).mask
                for mode, grounder in (("per-step", per_step), ("tracked", tracked)):
                    t0 = time.perf_counter()
                    got = grounder.ground(obs, cloud, target, names).mask
                    seconds[mode].append(time.perf_counter() - t0)
                    stats[(task, mode)].append(iou(got, want))
            inner_calls["tracked"].append(tracked.inner_calls)
            inner_calls["per-step"].append(len(episode.steps))

    rows = []
    for task in args.tasks:
        row = {"task": task}
        for mode in ("per-step", "tracked"):
            v = np.array(stats[(task, mode)])
            row[mode] = {"mean_iou": float(v.mean()), "wrong_steps": float((v < 0.5).mean()), "steps": len(v)}
        rows.append(row)
    allv = {m: np.array([x for (t, mm), v in stats.items() if mm == m for x in v]) for m in ("per-step", "tracked")}
    clip_label = f"CLIP {args.clip_model} {clip_options}, reacquire {args.reacquire}"
    grounder = clip_label if args.clip_model else f"oracle + noise (drop {args.drop}, jump {args.jump})"
    print(f"machine: {describe_machine()}; grounder: {grounder}; {args.seeds} expert episodes per task ({args.split})")
    print("| task | per-step IoU | tracked IoU | per-step steps with IoU < 0.5 | tracked steps with IoU < 0.5 |")
    print("|---|---|---|---|---|")
    for r in rows + [{"task": "**all**", **{m: {"mean_iou": float(allv[m].mean()),
                                                "wrong_steps": float((allv[m] < 0.5).mean())}
                                            for m in allv}}]:
        a, b = r["per-step"], r["tracked"]
        print(f"| {r['task']} | {a['mean_iou']:.2f} | {b['mean_iou']:.2f} | {100 * a['wrong_steps']:.0f} % "
              f"| {100 * b['wrong_steps']:.0f} % |")
    for mode in ("per-step", "tracked"):
        print(f"{mode}: {1000 * np.median(seconds[mode]):.1f} ms per step (median), grounder runs per episode "
              f"{np.mean(inner_calls[mode]):.1f}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"grounder": grounder, "rows": rows, "machine": describe_machine(),
                       "ms_per_step": {m: 1000 * float(np.median(v)) for m, v in seconds.items()},
                       "grounder_runs_per_episode": {m: float(np.mean(v)) for m, v in inner_calls.items()}}, f,
                      indent=1)


if __name__ == "__main__":
    main()
