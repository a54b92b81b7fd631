"""``abm render``: re-render a scene into the five virtual views and save them as PNGs."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from abm.geometry import Workspace, fuse_cameras
from abm.render import OrthographicRenderer, center_pixel_mask
from abm.render.synthetic import synthetic_scene

if TYPE_CHECKING:  # numpy is imported by the command itself, so `abm --help` stays fast
    import numpy as np


def _to_uint8(img: np.ndarray) -> np.ndarray:
    import numpy as np

    out: np.ndarray = (np.clip(img, 0.0, 1.0) * 255).round().astype(np.uint8)
    return out


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch
    from PIL import Image


    obs, names = synthetic_scene(seed=args.seed, resolution=args.camera_resolution)
    workspace = Workspace()
    cloud = fuse_cameras(obs, workspace)
    seg = cloud.gather({name: frame.segmentation for name, frame in obs.cameras.items()
                        if frame.segmentation is not None})  # the synthetic scene's cameras all have one
    target_id, target = next(iter(names.items()))
    mask = torch.from_numpy((seg == target_id).astype(np.float32))[:, None]
    renderer = OrthographicRenderer(workspace, args.resolution, splat_radius=args.splat, device=args.device)
    views = renderer.render(torch.from_numpy(cloud.xyz), torch.from_numpy(cloud.rgb), extra=mask)
    centers = center_pixel_mask(views.extra[0, :, 0]).cpu().numpy()

    args.out.mkdir(parents=True, exist_ok=True)
    for name, frame in obs.cameras.items():
        Image.fromarray(frame.rgb).save(args.out / f"camera_{name}.png")
    tiles = []
    for vi, view in enumerate(renderer.views):
        rgb = views.rgb[0, vi].permute(1, 2, 0).cpu().numpy()
        depth = 1.0 - views.depth[0, vi, 0].cpu().numpy() / workspace.size
        marked = rgb.copy()
        rows, cols = np.nonzero(centers[vi])
        for r, c in zip(rows, cols, strict=True):
            marked[max(r - 3, 0):r + 4, max(c - 3, 0):c + 4] = (1.0, 0.0, 1.0)
        tile = np.concatenate([marked, np.repeat(depth[..., None], 3, -1),
                               np.repeat(views.extra[0, vi, 0].cpu().numpy()[..., None], 3, -1)], axis=0)
        Image.fromarray(_to_uint8(tile)).save(args.out / f"view_{view}.png")
        tiles.append(tile)
    Image.fromarray(_to_uint8(np.concatenate(tiles, axis=1))).save(args.out / "views.png")
    print(f"scene: seed {args.seed}, {len(cloud)} points from {len(obs.cameras)} cameras, target {target!r}")
    print(f"wrote {len(obs.cameras)} camera images and {len(renderer.views)} virtual views to {args.out}/")
    print(f"overview: {args.out / 'views.png'} (rows: RGB with the target's centre pixel in magenta, depth, mask)")
    return 0
