"""``abm clip train``: render an image-text set from the simulator and train the benchmark CLIP on it.

Registered by :mod:`abm.grounding.commands`. The trained folder loads everywhere a CLIP model is accepted
(``--clip-model DIR``, ``load_clip(DIR)``, ``make_grounder("clip", model=DIR)``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

from abm.configuration import WORKERS, count, float_range, int_range, positive_int, seed_int
from abm.files import write_text_atomic

log = logging.getLogger("abm")

DEFAULT_SHARDS = 70
DEFAULT_HELDOUT_SHARDS = 4
HELDOUT_SEED = 1
# Mirrors abm.grounding.clip_train.TrainConfig (not imported here so `abm --help` stays light).
DEFAULT_STEPS, DEFAULT_BATCH, DEFAULT_LR, DEFAULT_MINUTES = 1600, 48, 5e-4, 35.0


def register(subparsers: argparse._SubParsersAction) -> None:
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
    t.set_defaults(func=run_train)
    p.set_defaults(func=lambda args: p.print_help() or 1)


def run_train(args: argparse.Namespace) -> int:
    import torch

    from abm.grounding.clip import load_clip
    from abm.grounding.clip_data import build_dataset, load_dataset
    from abm.grounding.clip_train import (
        CHECKPOINT,
        SUMMARY,
        TrainConfig,
        load_training_state,
        train,
        zero_shot_accuracy,
    )

    if args.steps < 1 or args.batch < 2 or args.shards < 1:
        raise ValueError("--steps must be >= 1, --batch >= 2 and --shards >= 1")  # abm: error: ...
    if (args.out / CHECKPOINT).is_file() and not args.resume:
        raise ValueError(f"{args.out} already holds a training run; pass --resume to continue it or choose "
                         "another --out")
    if args.resume and (args.out / CHECKPOINT).is_file():
        load_training_state(args.out / CHECKPOINT)  # a crafted or foreign checkpoint is refused before rendering
    torch.set_num_threads(args.threads)
    if args.threads > 1 and "OMP_WAIT_POLICY" not in os.environ:
        log.info("hint: on a shared machine start with OMP_WAIT_POLICY=PASSIVE; busy-waiting OpenMP threads "
                 "made training ~4x slower here when another process used a core")
    data_dir = args.data or args.out / "data"
    start = time.perf_counter()
    build_dataset(data_dir, args.shards, base_seed=args.seed, workers=args.workers, progress=not args.no_progress)
    render_s = time.perf_counter() - start
    data = load_dataset(data_dir, args.shards)
    log.info("dataset %s: %d samples (%.0f s rendering in this call)", data_dir, len(data), render_s)
    config = TrainConfig(steps=args.steps, batch_size=args.batch, lr=args.lr, seed=args.seed, threads=args.threads,
                         max_minutes=args.minutes or None)
    summary = train(data, args.out, config, resume=args.resume, progress=not args.no_progress,
                    extra_summary={"data": str(data_dir), "shards": args.shards})
    if args.heldout_shards > 0:
        heldout = Path(str(data_dir) + "_heldout")
        build_dataset(heldout, args.heldout_shards, base_seed=args.seed + HELDOUT_SEED, workers=args.workers,
                      progress=not args.no_progress)
        backbone = load_clip(str(args.out), device="cpu")
        summary["zero_shot"] = zero_shot_accuracy(backbone, load_dataset(heldout, args.heldout_shards))
        summary["zero_shot"]["data"] = str(heldout)
        write_text_atomic(args.out / SUMMARY, json.dumps(summary, indent=2) + "\n")
    final = summary.get("final") or {}
    print(f"trained {summary['steps']} steps in {summary['train_seconds'] / 60:.1f} min on {summary['samples']} "
          f"samples; final loss {final.get('loss')} (contrastive {final.get('contrastive')}, dense "
          f"{final.get('dense')})")
    if "zero_shot" in summary:
        z = summary["zero_shot"]
        print(f"zero-shot accuracy on {z['crops']} held-out crops of {z['classes']} objects: "
              f"{z['accuracy']:.3f} (CLS), {z['dense_accuracy']:.3f} (pooled dense features)")
    print(f"model folder: {args.out} (use --clip-model {args.out})")
    return 0
