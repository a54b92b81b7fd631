"""Figure for docs/grounding.md: one put_in_container demonstration, the instruction split into two
sub-goals, and the mask the policy attends to at each keyframe step (the five virtual views, the active
target tinted cyan).

Usage: python scripts/figures/subgoal_masks.py [--seed 1] [--out docs/images/subgoal_masks.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from abm.geometry import Workspace
from abm.grounding.conditioning import active_role
from abm.grounding.visualize import hstack, label, vstack
from abm.sim.env import make_env, run_expert
from abm.viewer import record_from_episode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("docs/images/subgoal_masks.png"))
    args = parser.parse_args()
    with make_env("put_in_container", "seen", args.seed, resolution=128) as env:
        episode = run_expert(env)
    x, y = episode.target_names
    scene = record_from_episode(episode, workspace=Workspace(center=(0.5, 0.0, 0.15), size=0.6), view_resolution=96)
    rows = []
    for step, (obs, action) in zip(scene.steps, episode.steps, strict=True):
        target = (x, y)[active_role(obs.gripper_open, 2)]  # the policy's rule: Y while the gripper holds X
        row = hstack([label(v, n) for v, n in zip(step.views, scene.view_names, strict=True)])
        rows.append(label(row, f"step {step.index} ({action.kind}): mask of '{target}'"))
    image = label(label(vstack(rows), f"sub-goal 1: grasp X = {x};  sub-goal 2: place it in Y = {y}"),
                  f'"{episode.instruction}"')
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(image)).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
