"""How well a policy fits the rotation labels of its own training keyframes, per task and keyframe kind.

Every keyframe of the demonstrations (the tasks and seen split a run trained on) is predicted teacher-forced,
as in training, without and with the training augmentation; the table gives the mean cross-entropy (nats) of
the roll, pitch and yaw bins per task and keyframe kind, beside the yaw's chance line for the keyframes'
symmetry (ln 36 two-fold, ln 18 four-fold, 0 round) and the prior of a model that knows only the task and the
kind (:mod:`abm.evaluation.rotation_fit`). ``--json`` also writes the rows.

Usage: python benchmarks/rotation_fit.py --run RUN --data DATA [--tasks place_food take_off_pan] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

import torch

from abm.data.episode_store import EpisodeStore
from abm.data.keyframes import EpisodeSource, KeyframeDataset
from abm.evaluation.rotation_fit import FitRow, rotation_fit
from abm.machine import describe_machine
from abm.policy import KeyframePolicy


def table(rows: list[tuple[bool, FitRow]]) -> str:
    """Markdown table of fit rows (augmentation flag, row)."""
    lines = ["| augmentation | task | keyframe | keyframes | x (roll) | y (pitch) | z (yaw) | yaw chance | yaw prior |",
             "|---|---|---|---|---|---|---|---|---|"]
    for augment, r in rows:
        x, y, z = r.cross_entropy
        lines.append(f"| {'on' if augment else 'off'} | {r.task} | {r.keyframe} | {r.keyframes} | {x:.2f} | {y:.2f} "
                     f"| {z:.2f} | {r.yaw_chance:.2f} | {r.yaw_prior:.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, help="run folder, checkpoint or zoo file")
    p.add_argument("--data", required=True, help="the episode store the run trained on")
    p.add_argument("--tasks", nargs="+", default=None, help="tasks to score (default: every task in DATA)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = p.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    policy = KeyframePolicy.from_checkpoint(args.run).eval()
    store = EpisodeStore(args.data)
    indices = store.select(tasks=args.tasks, splits=["seen"])
    if not indices:
        raise SystemExit(f"no seen episodes of {args.tasks or 'any task'} in {args.data}")
    rows: list[tuple[bool, FitRow]] = []
    for augment in (False, True):
        dataset = KeyframeDataset(EpisodeSource(store, indices), policy.workspace, policy.grounder_config,
                                  **policy.sample_options(), augment=augment, seed=0)
        rows += [(augment, r) for r in rotation_fit(policy, dataset)]
    print(f"machine: {describe_machine()}; {args.run} on {len(indices)} episodes of {args.data}; "
          f"{time.perf_counter() - started:.0f} s")
    print(table(rows))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([{"augment": a, **asdict(r)} for a, r in rows], indent=1) + "\n")


if __name__ == "__main__":
    main()
