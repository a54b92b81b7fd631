"""``abm train``: behaviour cloning of one policy variant on an episode store.

Single process::

    abm train --method abm --preset small --data data/ --tasks pick_block --steps 2000 --batch 8 --out runs/abm

Several processes / GPUs / nodes (DistributedDataParallel; gloo on CPU, nccl on CUDA)::

    torchrun --nproc_per_node 4 -m abm.cli train --device cuda ... --out runs/abm
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

from abm.policy.variants import VARIANTS


def parse_override(text: str) -> tuple[str, Any]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--set expects KEY=VALUE, got {text!r}")
    key, value = text.split("=", 1)
    try:
        return key.strip(), json.loads(value)
    except json.JSONDecodeError:
        return key.strip(), value


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train",
        help="train a policy variant (abm, rvt, ifd, ablations) by behaviour cloning",
        description="Train a multi-view transformer policy on keyframes of expert demonstrations. "
        "Checkpoints go to OUT/checkpoints; --resume continues exactly where an interrupted run stopped. "
        "Launch with `torchrun --nproc_per_node N -m abm.cli train ...` for data-parallel training.",
    )
    p.add_argument("--method", required=True, choices=sorted(VARIANTS), help="policy variant")
    p.add_argument("--preset", default="small", choices=["small", "paper"], help="model size preset")
    p.add_argument("--data", type=Path, help="episode store folder (from `abm data generate`)")
    p.add_argument("--synthetic", type=int, default=0, metavar="N",
                   help="train on N built-in synthetic block episodes instead of --data (smoke tests)")
    p.add_argument("--tasks", nargs="+", help="tasks to train on (default: all in the store)")
    p.add_argument("--splits", nargs="+", default=["seen"], help="episode splits to use (default: seen)")
    p.add_argument("--steps", type=int, required=True, help="total optimiser steps")
    p.add_argument("--batch", type=int, default=8, help="samples per step per process (default 8)")
    p.add_argument("--out", type=Path, required=True, help="run folder")
    p.add_argument("--grounder", default="oracle", choices=["oracle", "clip"], help="target-object grounding")
    p.add_argument("--clip-model", help="CLIP weights for --grounder/--language clip: hub name, local folder, "
                   "or 'tiny' (random tiny CLIP, tests only); default: the grounding package's default")
    p.add_argument("--clip-device", help="device of the CLIP model (default: CUDA when available)")
    p.add_argument("--language", choices=["hash", "clip"],
                   help="language encoder (default: clip with --grounder clip, else hash)")
    p.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    p.add_argument("--lr", type=float, help="peak learning rate (default 1e-4 x global batch)")
    p.add_argument("--optimizer", choices=("lamb", "adamw"), default="lamb",
                   help="LAMB (paper) or AdamW (faster convergence in short CPU runs)")
    p.add_argument("--warmup", type=int, help="warm-up steps (default min(2000, steps/20))")
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--grad-clip", type=float, default=1.0, help="max gradient norm (0 = off)")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    p.add_argument("--checkpoint-every", type=int, default=1000, help="steps between checkpoints")
    p.add_argument("--keep-checkpoints", type=int, default=3, help="periodic checkpoints kept (0 = all)")
    p.add_argument("--log-every", type=int, default=10, help="steps between log rows")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="continue from the latest checkpoint in --out")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the run already in --out (default: refuse, so no run is lost)")
    p.add_argument("--no-augment", action="store_true", help="disable SE(3) augmentation")
    p.add_argument("--set", dest="overrides", type=parse_override, action="append", default=[], metavar="KEY=VALUE",
                   help="override a policy config field, e.g. --set resolution=64 (repeatable)")
    p.add_argument("--cameras", nargs="+", help="cameras to fuse (default: all)")
    p.add_argument("--camera-resolution", type=int, default=64, help="camera side for --synthetic episodes")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError

    try:
        import torch_optimizer  # noqa: F401
    except ImportError as err:
        raise CommandError("training needs torch-optimizer (LAMB): pip install 'abm[train]'") from err
    from abm.train.loop import TrainConfig, train

    if args.steps < 1 or args.batch < 1:
        raise CommandError("--steps and --batch must be positive")
    if args.data is None and args.synthetic <= 0:
        raise CommandError("give --data DIR (an episode store) or --synthetic N")
    if args.data is not None and not Path(args.data).is_dir():
        raise CommandError(f"--data {args.data} is not a folder")
    cfg = TrainConfig(
        method=args.method, preset=args.preset, out=args.out, data=args.data, tasks=args.tasks,
        splits=args.splits, steps=args.steps, batch=args.batch, lr=args.lr, optimizer=args.optimizer,
        warmup=args.warmup, weight_decay=args.weight_decay, grad_clip=args.grad_clip,
        checkpoint_every=args.checkpoint_every,
        keep_checkpoints=args.keep_checkpoints, log_every=args.log_every, workers=args.workers,
        device=args.device, grounder=args.grounder, language=args.language, seed=args.seed,
        resume=args.resume, overwrite=args.overwrite, augment=not args.no_augment,
        policy_overrides=dict(args.overrides),
        camera_names=args.cameras, progress=not args.no_progress,
        grounder_options={k: v for k, v in (("model", args.clip_model), ("device", args.clip_device)) if v},
    )
    if cfg.grounder == "oracle" and cfg.grounder_options:
        if cfg.language != "clip":
            raise CommandError("--clip-model/--clip-device need --grounder clip or --language clip")
    episodes = None
    if args.data is None:
        from abm.train.synthetic import synthetic_episodes

        episodes = synthetic_episodes(args.synthetic, args.camera_resolution)
    summary = train(cfg, episodes=episodes)
    if int(os.environ.get("RANK", "0")) == 0:
        loss = summary["final_loss"].get("total", float("nan"))
        print(f"abm train: {summary['steps']} steps, final loss {loss:.4f}, checkpoint {summary['checkpoint']}")
    return 0
