"""``abm render``: re-render a scene into the five virtual views and save them as PNGs."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import int_range, seed_int


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "render",
        help="render the built-in synthetic scene into the 5 virtual views (PNG)",
        description="Fuse the cameras of the built-in synthetic scene into a point cloud, re-render it into "
        "the five orthographic virtual views (RGB, depth and the target mask) and write PNGs.",
    )
    p.add_argument("--out", type=Path, default=Path("out/render"), help="output folder (default: out/render)")
    p.add_argument("--seed", type=seed_int, default=0, help="scene seed (block colours and positions)")
    p.add_argument("--camera-resolution", type=int_range(16, 2048), default=128, help="camera image side in pixels")
    p.add_argument("--resolution", type=int_range(16, 2048), default=220, help="virtual view side in pixels")
    p.add_argument("--splat", type=int_range(0, 16), default=1, help="splat radius in pixels (closes holes)")
    p.add_argument("--device", default="cpu", help="torch device for the renderer (cpu, cuda)")
    p.set_defaults(func="abm.cli.commands.render:run")
