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

from abm.configuration import (
    add_config_arguments,
    check_overrides,
    clip_model_help,
    config_from_args,
    count,
    int_range,
    overrides_from_args,
)
from abm.policy.config import PolicyConfig
from abm.train.config import TrainConfig

POLICY_DEST = "policy__"


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
    p.add_argument("--config", metavar="RECIPE",
                   help="a recipe file (YAML: option names to values, policy overrides under 'policy:') or a "
                   "built-in recipe (cpu, quickstart, seen_unseen; the repository's configs/ folder); flags given "
                   "on the command line override it")
    add_config_arguments(p, TrainConfig)  # one flag per TrainConfig field, help from its docstring
    add_config_arguments(p, PolicyConfig, overrides_only=True, exclude=("variant", "preset", "extra"),
                         dest_prefix=POLICY_DEST, title="policy (overrides of the --preset; saved with the run)")
    p.add_argument("--synthetic", type=count, default=0, metavar="N",
                   help="train on N built-in synthetic block episodes instead of --data (smoke tests)")
    p.add_argument("--clip-model", help=clip_model_help("for --grounder clip / --language clip"))
    p.add_argument("--clip-device", help="device of the CLIP model (default: CUDA when available)")
    p.add_argument("--set", dest="overrides", type=parse_override, action="append", default=[], metavar="KEY=VALUE",
                   help="override a policy config field, e.g. --set resolution=64 (repeatable)")
    p.add_argument("--camera-resolution", type=int_range(16, 1024), default=64,
                   help="camera side for --synthetic episodes")
    p.set_defaults(func=run, config_sections={"policy": POLICY_DEST})

    e = subparsers.add_parser(
        "export",
        help="write a run's checkpoint without its training state (optionally in bfloat16) for deployment",
        description="Copy a checkpoint's weights, configs and grounder/language specs into one file that "
        "abm eval --run, abm run --run and KeyframePolicy.from_checkpoint load like a training checkpoint; "
        "the optimizer state and RNGs are left out (~3x smaller, ~6x with --dtype bfloat16).",
    )
    e.add_argument("--run", required=True, help="run folder (its latest checkpoint) or a checkpoint file")
    e.add_argument("--out", required=True, help="the exported .pt file")
    e.add_argument("--dtype", choices=("float32", "bfloat16", "float16"), default="float32",
                   help="storage dtype of the floating-point weights (default: float32, unchanged)")
    e.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    e.set_defaults(func=run_export)


def run_export(args: argparse.Namespace) -> int:
    import logging

    import torch

    from abm.files import FolderLock
    from abm.policy.checkpoint import check_export_target, export_checkpoint, resolve_checkpoint

    src = resolve_checkpoint(args.run)
    dtype = None if args.dtype == "float32" else getattr(torch, args.dtype)
    check_export_target(src, args.out, args.overwrite)
    with FolderLock(Path(args.out).parent, "abm export"):  # not while another command writes that folder
        out = export_checkpoint(src, args.out, dtype)
    logging.getLogger("abm").info("exported %s (%.1f MiB) -> %s (%.1f MiB)", src, src.stat().st_size / 2**20,
                                  out, out.stat().st_size / 2**20)
    return 0


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError

    if args.optimizer == "lamb":
        try:
            import torch_optimizer  # noqa: F401
        except ImportError as err:
            raise CommandError("--optimizer lamb needs torch-optimizer: pip install 'abm[train]'") from err
    from abm.train.loop import train

    if args.steps < 1 or args.batch < 1:
        raise CommandError("--steps and --batch must be positive")
    if args.data is None and args.synthetic <= 0:
        raise CommandError("give --data DIR (an episode store) or --synthetic N")
    if args.data is not None and not Path(args.data).is_dir():
        raise CommandError(f"--data {args.data} is not a folder")
    try:
        overrides = check_overrides(PolicyConfig, dict(args.overrides))
    except ValueError as err:
        raise CommandError(str(err)) from None
    cfg = config_from_args(
        TrainConfig, args, policy_overrides={**overrides_from_args(args, POLICY_DEST), **overrides},
        grounder_options={k: v for k, v in (("model", args.clip_model), ("device", args.clip_device)) if v})
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
        if (Path(cfg.out) / "log.csv").is_file():
            from abm.evaluation.report import plot_training_curves

            curve = plot_training_curves({cfg.method: cfg.out}, Path(cfg.out) / "training_curve.png")
            print(f"abm train: training curve {curve}")
    return 0
