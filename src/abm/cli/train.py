"""``abm train``: behaviour cloning of one policy variant on an episode store.

Single process::

    abm train --method abm --preset small --data data/ --tasks pick_block --steps 2000 --batch 8 --out runs/abm

Several processes / GPUs / nodes (DistributedDataParallel; gloo on CPU, nccl on CUDA)::

    torchrun --nproc_per_node 4 -m abm.cli train --device cuda ... --out runs/abm
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from abm.configuration import (
    GPU_CLIP_MODEL,
    add_config_arguments,
    clip_model_help,
    count,
    int_range,
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


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    for action in p._actions:  # no --grounder: the order every command uses (abm.grounding.default)
        if action.dest == "grounder":
            action.default = None
            action.help = (f"target-object grounding, {' or '.join(action.choices or ())} (default: --clip-model if "
                           "given, else the pretrained CLIP if cached, else the committed benchmark CLIP "
                           "(models/benchmark-clip), else the oracle with a warning; --synthetic and --resume: "
                           "oracle / the run's own)")
    add_config_arguments(p, PolicyConfig, overrides_only=True, exclude=("variant", "preset", "extra"),
                         dest_prefix=POLICY_DEST, title="policy (overrides of the --preset; saved with the run)")
    p.add_argument("--synthetic", type=count, default=0, metavar="N",
                   help="train on N built-in synthetic block episodes instead of --data (smoke tests)")
    p.add_argument("--clip-model", help=clip_model_help(
        "for --grounder clip / --language clip (given without --grounder: the CLIP grounder)",
        default=f"without --grounder, the grounder order's CLIP; with --grounder given, {GPU_CLIP_MODEL}"))
    p.add_argument("--clip-device", help="device of the CLIP model (default: CUDA when available)")
    p.add_argument("--set", dest="overrides", type=parse_override, action="append", default=[], metavar="KEY=VALUE",
                   help="override a policy config field, e.g. --set resolution=64 (repeatable)")
    p.add_argument("--camera-resolution", type=int_range(16, 1024), default=64,
                   help="camera side for --synthetic episodes")
    p.set_defaults(func="abm.cli.commands.train:run", config_sections={"policy": POLICY_DEST})

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
    e.set_defaults(func="abm.cli.commands.export:run")
