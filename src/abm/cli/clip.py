"""``abm clip train``: render an image-text set from the simulator and train the benchmark CLIP on it.

The parser; the command is :mod:`abm.cli.commands.clip`. The trained folder loads everywhere a CLIP model is
accepted (``--clip-model DIR``, ``load_clip(DIR)``, ``build_grounder({"kind": "clip", "model": DIR})``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import WORKERS, count, float_range, int_range, positive_int, seed_int

DEFAULT_SHARDS = 70
DEFAULT_HELDOUT_SHARDS = 4
# Mirrors abm.clip_training.train.ClipTrainConfig (not imported here so `abm --help` stays light).
DEFAULT_STEPS, DEFAULT_BATCH, DEFAULT_LR, DEFAULT_MINUTES = 1600, 48, 5e-4, 35.0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("clip", help="the benchmark CLIP: train one on simulator renders",
                              description="Commands for the benchmark CLIP model (see docs/grounding.md).")
    sub = p.add_subparsers(dest="clip_command", metavar="SUBCOMMAND")
    t = sub.add_parser(
        "train", help="render an image-text set from the simulator and train a small CLIP on it (resumable)",
        description="Render every catalog object in random scenes (shards cached under --data), train a small "
        "CLIP contrastively plus a dense patch loss on 2 CPU cores, and save a transformers folder that "
        "--clip-model DIR / load_clip(DIR) loads. Then measure zero-shot accuracy on held-out renders.",
    )
    t.add_argument("--out", type=Path, required=True, help="model folder to write")
    t.add_argument("--data", type=Path, default=None, help="dataset cache folder (default OUT/data)")
    t.add_argument("--shards", type=positive_int, default=DEFAULT_SHARDS,
                   help=f"training shards to render, ~290 samples each (default {DEFAULT_SHARDS})")
    t.add_argument("--heldout-shards", type=count, default=DEFAULT_HELDOUT_SHARDS,
                   help=f"held-out shards (other seeds) for the zero-shot accuracy (default {DEFAULT_HELDOUT_SHARDS}; "
                   "0 skips it)")
    t.add_argument("--steps", type=positive_int, default=DEFAULT_STEPS,
                   help=f"optimiser steps (default {DEFAULT_STEPS})")
    t.add_argument("--minutes", type=float_range(0.0), default=DEFAULT_MINUTES,
                   help="training time budget; the learning-rate schedule follows whichever of steps and time "
                   f"runs out first (default {DEFAULT_MINUTES:g}; 0 = steps only)")
    t.add_argument("--batch", type=int_range(2), default=DEFAULT_BATCH, help=f"batch size (default {DEFAULT_BATCH})")
    t.add_argument("--lr", type=float_range(0.0, low_open=True), default=DEFAULT_LR,
                   help=f"peak learning rate (default {DEFAULT_LR:g})")
    t.add_argument("--workers", type=int_range(1, 256), default=WORKERS, help="rendering processes")
    t.add_argument("--threads", type=int_range(1, 256), default=2, help="torch threads for training (default 2)")
    t.add_argument("--seed", type=seed_int, default=0, help="data and initialisation seed (default 0)")
    t.add_argument("--resume", action="store_true", help="continue the run in --out (rendering always resumes)")
    t.add_argument("--no-progress", action="store_true", help="no progress bars")
    t.set_defaults(func="abm.cli.commands.clip:run_train")

    def usage(args: argparse.Namespace) -> int:  # the group without a sub-command
        p.print_help()
        return 1

    p.set_defaults(func=usage)
