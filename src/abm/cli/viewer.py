"""``abm view``: a local 3-D web viewer of an episode or of a policy rollout."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import SPLITS, clip_model_help, count, port_number, seed_int
from abm.grounding.config import GROUNDERS


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "view", help="3-D browser viewer: point cloud, mask field, virtual views, heatmaps and keyframes",
        description="Serve a local web page (viser; works offline) showing, for each keyframe step, the fused "
        "point cloud coloured by RGB or by mask-field score, the target's points, the workspace cube, the five "
        "virtual cameras with their views (mask in cyan, the predicted translation heatmap on top), and the "
        "expert's (green) and predicted (orange) keyframes. Sources: --episode FILE (a demonstration; with --run "
        "also what the policy saw and predicted at each step), or --run RUN --task TASK (roll the policy out on "
        "the seeded scene abm eval uses).")
    p.add_argument("--episode", type=Path, help="episode file (.h5) to show")
    p.add_argument("--run", type=Path, help="training run folder or checkpoint: show its views and predictions")
    p.add_argument("--task", help="roll --run out on this ABM-Bench task instead of showing --episode")
    p.add_argument("--split", default="seen", choices=SPLITS, help="rollout split")
    p.add_argument("--seed", type=seed_int, default=1_000_000,
                   help="rollout scene seed (abm eval's outcome log lists the seed of each episode)")
    p.add_argument("--steps", type=count, nargs="+", metavar="K", help="only these steps of --episode")
    p.add_argument("--grounder", choices=GROUNDERS.names(per_frame=True),
                   help="grounder (default: the checkpoint's, or oracle)")
    p.add_argument("--clip-model", help=clip_model_help(
        f"for --grounder {' or '.join(GROUNDERS.names(per_frame=True, clip=True))}", default=None))
    p.add_argument("--device", default="cpu", help="torch device of the policy")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: localhost only)")
    p.add_argument("--port", type=port_number, default=8080, help="port (default: 8080)")
    p.add_argument("--screenshot", type=Path, metavar="PNG",
                   help="save a headless-Chromium screenshot of the page and exit instead of serving")
    p.set_defaults(func="abm.cli.commands.viewer:run")
