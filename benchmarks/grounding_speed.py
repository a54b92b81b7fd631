"""Time Object Mask Field generation: 4 cameras at 128x128, CLIP ViT-B/16@224 and ViT-L/14@336 sized models.

Usage: python benchmarks/grounding_speed.py [--models vit-b16 vit-l14-336] [--device cpu|cuda]
                                            [--dtype float32|float16] [--repeats 3]

The models have random weights (same architecture, same cost as the pretrained ones), so no download is
needed. Each timed call is one full ``ClipGrounder.ground`` with every cache disabled: the 4 camera images
go through the vision encoder as one batch (MaskCLIP path), the prompt and the 4 negative prompts through
the text encoder, then lifting to the fused cloud, softmax normalisation and threshold. The rendering of
the mask into the 5 virtual views (center-pixel masks) is timed separately. Prints the machine and a
markdown table of median seconds.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import ClipGrounder, GroundingCache, mask_views, random_clip
from abm.machine import describe_machine
from abm.render import OrthographicRenderer
from abm.render.synthetic import synthetic_scene


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def timed(fn, repeats: int, device: str, warmup: int = 1) -> float:
    """Median wall-clock seconds of ``fn()`` over ``repeats`` calls after ``warmup`` calls."""
    times = []
    for i in range(warmup + repeats):
        _sync(device)
        start = time.perf_counter()
        fn()
        _sync(device)
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["vit-b16", "vit-l14-336"])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--dtype", default=None, help="float32 (CPU default) or float16 (CUDA default)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=128, help="camera image side")
    args = parser.parse_args()

    obs, names = synthetic_scene(seed=0, resolution=args.resolution)
    cloud = fuse_cameras(obs, Workspace())
    renderer = OrthographicRenderer(Workspace(), 220, device=args.device)
    name = torch.cuda.get_device_name() if args.device.startswith("cuda") else describe_machine()
    print(f"device: {args.device} ({name}); {len(obs.cameras)} cameras at {args.resolution}x{args.resolution}, "
          f"{len(cloud)} points")
    print("| model | input | dtype | image encoder, 4 images (s) | text, 5 prompts (s) | mask field, total (s) "
          "| mask -> 5 views (s) |")
    print("|---|---|---|---|---|---|---|")
    for preset in args.models:
        backbone = random_clip(preset, seed=0, device=args.device, dtype=args.dtype)
        grounder = ClipGrounder(backbone=backbone, cache=GroundingCache(None, memory_items=0), cache_features=False)
        images = [obs.camera(n).rgb for n in cloud.camera_names]
        prompts = ["a photo of a red block", "a photo of an object", "a photo of a things", "a photo of a stuff",
                   "a photo of a texture"]
        with torch.inference_mode():
            t_img = timed(lambda b=backbone, x=images: b.dense_features(x), args.repeats, args.device)
            t_txt = timed(lambda b=backbone, p=prompts: b.text_features(p), args.repeats, args.device)

            def ground(g=grounder):
                g._text_memory.clear()  # count the text encoder too
                return g.ground(obs, cloud, "red block", names)

            t_all = timed(ground, args.repeats, args.device)
            field = ground()
            t_views = timed(lambda f=field: mask_views(renderer, cloud, f.mask), args.repeats, args.device)
        size = backbone.image_size
        print(f"| {preset} | {size}x{size} | {str(backbone.dtype).replace('torch.', '')} | {t_img:.3f} | "
              f"{t_txt:.3f} | {t_all:.3f} | {t_views:.3f} |", flush=True)
        del grounder, backbone


if __name__ == "__main__":
    main()
