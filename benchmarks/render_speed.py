"""Time the orthographic renderer: 5 views of 220x220 from random point clouds.

Usage: python benchmarks/render_speed.py [--device cpu|cuda] [--repeats 10]

Each point carries 10 channels (RGB + 7 extra, e.g. a mask and features); xyz and depth are
rendered on top. Prints the machine and a markdown table (median milliseconds per call).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from abm.geometry import Workspace
from abm.machine import describe_machine
from abm.render import OrthographicRenderer


def time_render(renderer: OrthographicRenderer, batch: int, points: int, repeats: int, device: str) -> float:
    ws = renderer.workspace
    lo, hi = torch.tensor(ws.lower, dtype=torch.float32), torch.tensor(ws.upper, dtype=torch.float32)
    xyz = (lo + (hi - lo) * torch.rand(batch, points, 3)).to(device)
    rgb = torch.rand(batch, points, 3, device=device)
    extra = torch.rand(batch, points, 7, device=device)
    times = []
    for i in range(repeats + 2):
        if device == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        renderer.render(xyz, rgb, extra)
        if device == "cuda":
            torch.cuda.synchronize()
        if i >= 2:  # warm-up
            times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    renderer = OrthographicRenderer(Workspace(), resolution=220, device=args.device)
    name = torch.cuda.get_device_name() if args.device == "cuda" else describe_machine()
    print(f"device: {args.device} ({name})")
    print("| points | batch | ms / call | ms / sample |")
    print("|---|---|---|---|")
    for points, batch in ((50_000, 1), (100_000, 1), (200_000, 1), (50_000, 8), (200_000, 8)):
        ms = time_render(renderer, batch, points, args.repeats, args.device)
        print(f"| {points // 1000}k | {batch} | {ms:.1f} | {ms / batch:.1f} |", flush=True)


if __name__ == "__main__":
    main()
