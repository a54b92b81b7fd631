"""Time Object Mask Field generation: 4 cameras at 128x128, CLIP ViT-B/16@224 and ViT-L/14@336 sized models.

Usage: python benchmarks/grounding_speed.py [--models vit-b16 vit-l14-336] [--device cpu|cuda]
                                            [--dtype float32|float16] [--repeats 3]

The models have random weights (same architecture, same cost as the pretrained ones), so no download is
needed. Each timed call is one full ``ClipGrounder.ground`` with every cache disabled: the 4 camera images
go through the vision encoder as one batch (MaskCLIP path), the prompt and the 4 negative prompts through
the text encoder, then lifting to the fused cloud, softmax normalisation and threshold. The rendering of
the mask into the 5 virtual views (center-pixel masks) is timed separately. Prints the machine and a
markdown table of median seconds.

The CLIP proposal grounder of the zoo's models on the keyframes of simulated episodes (``--episodes``): the
scripted expert runs each task once (``--tasks``, seen split, seed ``--seed``), its keyframe observations are
fused into clouds, and one fresh ``ClipGrounder`` per episode (``--clip-model``, every cache off, one torch
thread) grounds the episode's target at each keyframe in order, as a rollout does. Prints the CPU seconds per
grounding step and a digest of every step's mask, heatmap and decision. ``--against REF`` grounds the same
observations with the library of a ``git worktree`` of REF as well, in subprocesses run in turn (REF, this
tree, REF, ...; ``--rounds``), and says whether every step's mask, heatmap and decision are the same::

    OMP_NUM_THREADS=1 python benchmarks/grounding_speed.py --episodes --tasks place_food put_in_shelf \
        --against 65d6cab --rounds 3
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
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


def record_episodes(tasks: list[str], seed: int, out: Path) -> None:
    """Run the scripted expert on each task and pickle the keyframes' (observation, fused cloud, target)."""
    from abm.sim.env import make_env, run_expert

    steps = []
    for task in tasks:
        env = make_env(task, "seen", seed=seed)
        try:
            episode = run_expert(env)
        finally:
            env.close()
        target = episode.target_names[0]
        steps.append([(obs, fuse_cameras(obs, Workspace()), target) for obs, _ in episode.steps])
    out.write_bytes(pickle.dumps(steps))


def ground_episodes(path: Path, clip_model: str, save: Path | None = None) -> dict[str, object]:
    """Ground the pickled episodes, one fresh proposal grounder per episode: CPU s per step, a digest of each
    step's mask and decision (found), and of its heatmap and confidence; ``save``: an ``.npz`` of the heatmaps."""
    from abm.grounding.grounders import ClipGrounder

    torch.set_num_threads(1)
    episodes = pickle.loads(path.read_bytes())
    backbone = ClipGrounder(model=clip_model, device="cpu").backbone
    seconds, decisions, digests, heatmaps, calls = [], [], [], [], 0
    for steps in episodes:
        grounder = ClipGrounder(backbone=backbone, cache=GroundingCache(None, memory_items=0), cache_features=False,
                                mode="proposals")
        grounder.text_features(["warm up"])
        for obs, cloud, target in steps:
            start = time.process_time()
            field = grounder.ground(obs, cloud, target)
            seconds.append(time.process_time() - start)
            decisions.append(hashlib.sha1(field.mask.tobytes() + repr(field.found).encode()).hexdigest()[:12])
            digests.append(hashlib.sha1(field.heatmap.tobytes() + repr(field.confidence).encode()).hexdigest()[:12])
            heatmaps.append(field.heatmap)
        calls += grounder.backbone_calls
    if save is not None:
        np.savez(save, *heatmaps)
    return {"cpu_s_per_step": sum(seconds) / len(seconds), "steps": len(seconds), "decisions": decisions,
            "digests": digests, "images_encoded": calls}


def compare_episodes(args: argparse.Namespace) -> None:
    """Record the episodes once, ground them with this tree and (``--against``) a worktree of another commit."""
    here = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "episodes.pkl"
        if not data.exists():
            record_episodes(args.tasks, args.seed, data)
        trees = {"current": here}
        if args.against:
            trees = {"baseline": Path(tmp) / "baseline", **trees}
            subprocess.run(["git", "-C", str(here), "worktree", "add", "--detach", "-q", str(trees["baseline"]),
                            args.against], check=True)
        try:
            runs: dict[str, list[dict[str, object]]] = {name: [] for name in trees}
            for _ in range(args.rounds):
                for name, root in trees.items():
                    env = {**os.environ, "PYTHONPATH": str(root / "src"), "OMP_NUM_THREADS": "1"}
                    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--ground", str(data),
                                          "--clip-model", str(here / args.clip_model),
                                          "--save", str(Path(tmp) / f"{name}.npz")],
                                         env=env, check=True, capture_output=True, text=True).stdout
                    runs[name].append(json.loads(out.strip().splitlines()[-1]))
        finally:
            if args.against:
                subprocess.run(["git", "-C", str(here), "worktree", "remove", "--force", str(trees["baseline"])],
                               check=False)
        print(f"{describe_machine()}; tasks {' '.join(args.tasks)} (seed {args.seed}); {args.rounds} rounds, "
              "one thread")
        print("| tree | steps | images encoded | CPU s per grounding step (median of rounds) |")
        print("|---|---|---|---|")
        median = {}
        for name, rows in runs.items():
            median[name] = statistics.median(float(str(r["cpu_s_per_step"])) for r in rows)
            print(f"| {name} | {rows[0]['steps']} | {rows[0]['images_encoded']} | {median[name]:.4f} |")
        if args.against:
            masks = runs["baseline"][0]["decisions"] == runs["current"][0]["decisions"]
            heat = runs["baseline"][0]["digests"] == runs["current"][0]["digests"]
            with np.load(Path(tmp) / "baseline.npz") as a, np.load(Path(tmp) / "current.npz") as b:
                diff = max(float(np.abs(a[k] - b[k]).max()) for k in a.files)
            print(f"speed-up {median['baseline'] / median['current']:.2f}x; masks and decisions (found) of every step: "
                  f"{'identical' if masks else 'DIFFERENT'}; heatmaps and confidences: "
                  f"{'bit-identical' if heat else f'largest difference {diff:.1e}'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["vit-b16", "vit-l14-336"])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--dtype", default=None, help="float32 (CPU default) or float16 (CUDA default)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=128, help="camera image side")
    parser.add_argument("--episodes", action="store_true", help="the proposal grounder on simulated episodes")
    parser.add_argument("--tasks", nargs="+", default=["place_food", "put_in_shelf"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clip-model", default="models/benchmark-clip", help="CLIP of --episodes (checkout path)")
    parser.add_argument("--against", default=None, metavar="REF", help="with --episodes: also ground with REF")
    parser.add_argument("--rounds", type=int, default=3, help="with --episodes: runs per tree, taken in turn")
    parser.add_argument("--data", type=Path, default=None, help="with --episodes: keep the recorded episodes in "
                        "this pickle (reused when it exists)")
    parser.add_argument("--ground", type=Path, default=None, help=argparse.SUPPRESS)  # one subprocess's run
    parser.add_argument("--save", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.ground is not None:
        print(json.dumps(ground_episodes(args.ground, args.clip_model, args.save)))
        return
    if args.episodes:
        compare_episodes(args)
        return

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
