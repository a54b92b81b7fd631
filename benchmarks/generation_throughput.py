"""Measure demonstration-generation throughput (episodes/minute) and save camera montages.

Usage::

    python benchmarks/generation_throughput.py --episodes 6 --workers 2 [--resolution 128]
        [--montage-dir docs/images]

For each task, generates ``--episodes`` seen-split demonstrations with rendering (4 RGB-D-segmentation
cameras per keyframe) and HDF5 writing through :func:`abm.data.generate.generate` into a temporary
folder, and prints a Markdown table. With ``--montage-dir``, also writes ``<task>.png``: the four
cameras of the first keyframe of seed 0 as a 2x2 montage (front | left_shoulder / right_shoulder | wrist).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np


def save_montage(task: str, out_dir: Path, resolution: int) -> Path:
    from PIL import Image

    from abm.sim.env import make_env

    with make_env(task, "seen", 0, resolution=resolution) as env:
        obs = env.reset()
        instruction = env.instruction
    tiles = [obs.cameras[n].rgb for n in ("front", "left_shoulder", "right_shoulder", "wrist")]
    montage = np.concatenate([np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:], 1)], 0)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{task}.png"
    Image.fromarray(montage).save(path, optimize=True)
    print(f"{path}: {instruction}")
    return path


def main() -> None:
    from abm.data.generate import generate, trainable_tasks

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=trainable_tasks())
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--montage-dir", type=Path, default=None)
    args = parser.parse_args()
    if args.montage_dir is not None:
        for task in args.tasks:
            save_montage(task, args.montage_dir, args.resolution)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for task in args.tasks:
            report = generate(task, "seen", args.episodes, tmp, workers=args.workers,
                              resolution=args.resolution, progress=False)
            size = sum(p.stat().st_size for p in (Path(tmp) / task).rglob("*.h5")) / max(1, report.created)
            rows.append((task, report, size))
    print(f"\n{args.workers} worker(s), {args.resolution}x{args.resolution}, 4 cameras\n")
    print("| task | episodes | seconds | episodes/min | MB/episode |")
    print("|---|---|---|---|---|")
    for task, report, size in rows:
        print(f"| {task} | {report.created} | {report.seconds:.0f} | {report.episodes_per_minute:.1f} | "
              f"{size / 1e6:.2f} |")


if __name__ == "__main__":
    main()
