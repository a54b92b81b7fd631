"""Figure for docs/policy.md and docs/grounding.md: the two masks of a policy with ``destination_mask`` in the five
virtual views. One recorded demonstration per task (pick_block: the block and the target pad; place_wine: the
bottle and the wine rack), its first keyframe, the oracle grounder: the target's mask tinted cyan, the destination's
magenta, as the ``concat-full`` variant takes them (abm takes each one's centre pixel, marked by a ring).

Usage: python scripts/figures/destination_masks.py [--seed 0] [--out docs/images/destination_masks.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from abm.grounding.config import OracleGrounderConfig
from abm.grounding.visualize import blend, hstack, label, mark_pixels, to_uint8, upscale, vstack
from abm.language.roles import instruction_destination
from abm.policy import KeyframePolicy, PolicyConfig
from abm.render import center_pixel_mask
from abm.samples import collate
from abm.sim.env import make_env, run_expert

CYAN, MAGENTA = np.array([0, 200, 255], np.uint8), np.array([255, 0, 200], np.uint8)
SCALE = 2  # pixels of the figure per view pixel


def task_row(task: str, seed: int, policy: KeyframePolicy) -> np.ndarray:
    """One labelled row: the five views of ``task``'s first keyframe with both masks."""
    with make_env(task, "seen", seed, resolution=128) as env:
        episode = run_expert(env)
    obs = episode.steps[0][0]
    sample = policy.observe(obs, episode.instruction, episode.object_names)
    inputs = policy.model_inputs(collate([sample]))
    mask = inputs["mask"][0].float()  # (V, 2, H, W): the target's channel, the destination's
    rgb = inputs["images"][0, :, :3].permute(0, 2, 3, 1).numpy()
    centres = center_pixel_mask(mask)  # (V, 2, H, W): one pixel per view and mask
    views = []
    for v, name in enumerate(policy.config.views):
        image = to_uint8(rgb[v])
        for channel, colour in ((0, CYAN), (1, MAGENTA)):
            alpha = 0.75 * mask[v, channel].numpy()
            image = blend(image, np.broadcast_to(colour, image.shape), alpha)
        image = upscale(image, SCALE)
        for channel, colour in ((0, CYAN), (1, MAGENTA)):
            pixels = [(int(r) * SCALE + SCALE // 2, int(c) * SCALE + SCALE // 2)
                      for r, c in torch.nonzero(centres[v, channel]).tolist()]
            image = mark_pixels(image, pixels, radius=6, color=(int(colour[0]), int(colour[1]), int(colour[2])))
        views.append(label(image, name))
    target, destination = episode.target_names[0], instruction_destination(episode.instruction)
    return label(hstack(views), f'{task}: "{episode.instruction}": target (cyan) = {target}, destination '
                                f"(magenta) = {destination}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tasks", nargs="+", default=["pick_block", "place_wine"])
    parser.add_argument("--out", type=Path, default=Path("docs/images/destination_masks.png"))
    args = parser.parse_args()
    config = PolicyConfig.from_preset("small", "concat-full", destination_mask=True)
    policy = KeyframePolicy(config, {"kind": "hash", "dim": config.lang_dim}, OracleGrounderConfig())
    rows = [task_row(task, args.seed, policy) for task in args.tasks]
    image = label(vstack(rows), "the policy's two mask channels (destination_mask): target X and its destination")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(image)).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
