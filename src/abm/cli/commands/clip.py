"""``abm clip train``: render an image-text set from the simulator and train the benchmark CLIP on it.

The command; its parser is :mod:`abm.cli.clip`. The trained folder loads everywhere a CLIP model is accepted
(``--clip-model DIR``, ``load_clip(DIR)``, ``build_grounder({"kind": "clip", "model": DIR})``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

from abm.clip_training.data import build_dataset, load_dataset
from abm.clip_training.train import CHECKPOINT, SUMMARY, ClipTrainConfig, load_training_state, train, zero_shot_accuracy
from abm.errors import ConfigError, OutputError
from abm.files import write_text_atomic
from abm.grounding.clip import load_clip

log = logging.getLogger("abm")


HELDOUT_SEED = 1


def run_train(args: argparse.Namespace) -> int:
    import torch


    if args.steps < 1 or args.batch < 2 or args.shards < 1:
        raise ConfigError("--steps must be >= 1, --batch >= 2 and --shards >= 1")
    if (args.out / CHECKPOINT).is_file() and not args.resume:
        raise OutputError(f"{args.out} already holds a training run; pass --resume to continue it or choose "
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
    config = ClipTrainConfig(steps=args.steps, batch_size=args.batch, lr=args.lr, seed=args.seed, threads=args.threads,
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
