"""How well a policy fits its rotation labels on its own training keyframes, per Euler axis.

For every keyframe of the demonstrations (the tasks and seen split a run trained on), the policy predicts
with the rotation head pooled at the ground-truth heatmap, exactly as in training, and the cross-entropy of
each axis's bins against the label is averaged: without augmentation, and with the training augmentation
(the scene and the label turned and shifted, the label put back into its canonical member). A uniform guess
over ``n`` bins scores ``ln n``; for a top-down grasp with the two-fold gripper symmetry the yaw label
takes 36 of the 72 bins (ln 36 = 3.58). An axis near that has not been fitted even on the training scenes.

Usage: python benchmarks/rotation_fit.py --run RUN --data DATA [--tasks place_food take_off_pan]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
import torch.nn.functional as F

from abm.data.episode_store import EpisodeStore
from abm.data.keyframes import EpisodeSource, KeyframeDataset, collate
from abm.machine import describe_machine
from abm.policy import KeyframePolicy


def axis_cross_entropy(policy: KeyframePolicy, dataset: KeyframeDataset, batch: int = 16) -> list[float]:
    """Mean cross-entropy (nats) of the x, y and z Euler-angle bins over every sample of ``dataset``."""
    total = np.zeros(3)
    with torch.no_grad():
        for start in range(0, len(dataset), batch):
            samples = collate([dataset[j] for j in range(start, min(len(dataset), start + batch))])
            target = policy.targets(samples)
            out = policy.run_model(policy.model_inputs(samples), pool_weights=target["heatmap"])
            for axis in range(3):
                total[axis] += float(F.cross_entropy(out.rotation[:, axis].float(), target["rotation_bins"][:, axis],
                                                     reduction="sum"))
    return [float(v) / len(dataset) for v in total]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, help="run folder, checkpoint or zoo file")
    p.add_argument("--data", required=True, help="the episode store the run trained on")
    p.add_argument("--tasks", nargs="+", default=None, help="tasks to score (default: every task in DATA)")
    args = p.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    policy = KeyframePolicy.from_checkpoint(args.run).eval()
    store = EpisodeStore(args.data)
    indices = store.select(tasks=args.tasks, splits=["seen"])
    if not indices:
        raise SystemExit(f"no seen episodes of {args.tasks or 'any task'} in {args.data}")
    rows = []
    for augment in (False, True):
        dataset = KeyframeDataset(EpisodeSource(store, indices), policy.workspace, policy.grounder_config,
                                  **policy.sample_options(), augment=augment, seed=0)
        rows.append((augment, len(dataset), axis_cross_entropy(policy, dataset)))
    print(f"machine: {describe_machine()}; {args.run} on {len(indices)} episodes of {args.data}; "
          f"{time.perf_counter() - started:.0f} s")
    print("| augmentation | keyframes | x (roll) | y (pitch) | z (yaw) |\n|---|---|---|---|---|")
    for augment, n, ce in rows:
        print(f"| {'on' if augment else 'off'} | {n} | " + " | ".join(f"{v:.2f}" for v in ce) + " |")


if __name__ == "__main__":
    main()
