"""Figure for docs/policy.md: what a two-stage policy sees at one keyframe -- the five workspace views with the
coarse heatmap, and the five zoomed views around the coarse point with the fine heatmap (the target tinted cyan).

Usage: python scripts/figures/zoom_views.py --run RUN_OR_CKPT [--task place_food] [--seed 1000000]
    [--keyframe approach] [--out docs/images/zoom_views.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from abm.grounding.visualize import hstack, label, overlay_views, upscale, vstack
from abm.policy import KeyframePolicy
from abm.sim.env import make_env, run_expert


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a two-stage run folder or checkpoint")
    parser.add_argument("--task", default="place_food")
    parser.add_argument("--seed", type=int, default=1000000)
    parser.add_argument("--keyframe", default="approach", help="the expert keyframe kind to show")
    parser.add_argument("--out", type=Path, default=Path("docs/images/zoom_views.png"))
    args = parser.parse_args()
    policy = KeyframePolicy.from_checkpoint(args.run)
    if policy.zoom_model is None:
        raise SystemExit(f"{args.run} is a one-stage policy (zoom_size = 0)")
    with make_env(args.task, "seen", args.seed, resolution=128) as env:
        episode = run_expert(env)
        names = env.object_names
    step = next((i for i, (_, a) in enumerate(episode.steps) if a.kind == args.keyframe), None)
    if step is None:
        raise SystemExit(f"{args.task} has no {args.keyframe!r} keyframe")
    obs, label_action = episode.steps[step]
    seen = policy.explain(obs, episode.instruction, names)
    assert seen.zoom_images is not None and seen.zoom_heatmaps is not None and seen.zoom_center is not None
    coarse = overlay_views(seen.view_rgb, seen.view_target, seen.heatmaps)
    zoom_rgb = np.clip(seen.zoom_images[:, :3].transpose(0, 2, 3, 1), 0, 1)
    zoomed = overlay_views(zoom_rgb, None, seen.zoom_heatmaps)
    factor = max(coarse[0].shape[0] // zoomed[0].shape[0], 1)
    cfg = policy.config
    rows = [
        label(hstack([label(upscale(v, 2), n) for v, n in zip(coarse, seen.view_names, strict=True)]),
              f"coarse stage: {cfg.resolution}x{cfg.resolution} views of the {cfg.workspace_size:g} m workspace, "
              "coarse heatmap"),
        label(hstack([label(upscale(v, 2 * factor), n) for v, n in zip(zoomed, seen.view_names, strict=True)]),
              f"zoomed stage: {cfg.zoom_resolution}x{cfg.zoom_resolution} views of a {cfg.zoom_size:g} m cube around "
              "the coarse point, fine heatmap"),
    ]
    err = np.linalg.norm(seen.action.position - label_action.position) * 100
    title = (f'{args.task}, "{episode.instruction}", {args.keyframe} keyframe: predicted point '
             f"{err:.1f} cm from the expert's")
    image = label(vstack(rows), title)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(image)).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
