"""``abm train``: behaviour cloning of one policy variant on an episode store.

Single process::

    abm train --method abm --preset small --data data/ --tasks pick_block --steps 2000 --batch 8 --out runs/abm

Several processes / GPUs / nodes (DistributedDataParallel; gloo on CPU, nccl on CUDA)::

    torchrun --nproc_per_node 4 -m abm.cli train --device cuda ... --out runs/abm
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from pathlib import Path

from abm.cli.train import POLICY_DEST
from abm.configuration import (
    check_overrides,
    config_from_args,
    overrides_from_args,
)
from abm.data.episode_store import held_out_overlap
from abm.errors import ConfigError, ExternalError
from abm.evaluation.plots import run_loss_curves
from abm.grounding.default import default_grounder
from abm.policy.config import PolicyConfig
from abm.train.config import TrainConfig, grounding_from_flags
from abm.train.loop import train
from abm.train.synthetic import synthetic_episodes


def train_grounder(args: argparse.Namespace) -> tuple[str, str | None]:
    """``(grounder, clip model)`` of a training whose command line names no ``--grounder``: a resumed run's own,
    the oracle for ``--synthetic`` episodes, else :func:`abm.grounding.default.default_grounder` (the order every
    command uses, so ``abm train --config quickstart`` trains with the grounder the quickstart uses). The choice
    is printed before any work."""
    main = int(os.environ.get("RANK", "0")) == 0
    saved = Path(args.out) / "config.json" if args.out else None
    if args.resume and saved is not None and saved.is_file():
        train = TrainConfig.from_dict(json.loads(saved.read_text()).get("train", {}))  # any abm version's form
        grounder = train.grounder.kind
        model = {**train.language_config.clip_options(), **train.grounder.clip_options()}.get("model")
        if main:
            print(f"abm train: grounder: {grounder}{f' {model}' if model else ''} (the resumed run's own)")
        return grounder, args.clip_model or model
    if args.data is None:
        if main:
            print("abm train: grounder: oracle (--synthetic episodes; give --grounder clip for CLIP masks)")
        return "oracle", args.clip_model
    choice = default_grounder(args.clip_model, str(args.device))
    if main:
        print(choice.startup_line("train"))
    return choice.kind, choice.model or args.clip_model


def run(args: argparse.Namespace) -> int:
    if args.optimizer == "lamb":
        try:
            import torch_optimizer  # noqa: F401
        except ImportError as err:
            raise ExternalError("--optimizer lamb needs torch-optimizer: pip install 'abm[train]'") from err

    if args.steps < 1 or args.batch < 1:
        raise ConfigError("--steps and --batch must be positive")
    if args.data is None and args.synthetic <= 0:
        raise ConfigError("give --data DIR (an episode store) or --synthetic N")
    if args.data is not None and not Path(args.data).is_dir():
        raise ConfigError(f"--data {args.data} is not a folder")
    overrides = check_overrides(PolicyConfig, dict(args.overrides))
    if args.warmup is not None and args.warmup >= args.steps:
        logging.getLogger("abm").warning("abm train: --warmup %d is not shorter than --steps %d: the learning rate "
                                         "never reaches its peak", args.warmup, args.steps)
    if args.grounder is None:
        args.grounder, args.clip_model = train_grounder(args)
    grounder, language = grounding_from_flags(args.grounder, args.language, args.clip_model, args.clip_device)
    cfg = config_from_args(TrainConfig, args, policy={**overrides_from_args(args, POLICY_DEST), **overrides},
                           grounder=grounder, language=language)
    if cfg.val_data is not None and cfg.data is not None:
        overlap = held_out_overlap(cfg.data, cfg.val_data)
        if overlap:
            raise ConfigError(f"{overlap}: validation episodes must be held out (other scenes, in their own "
                              "folder: abm data generate --seed with seeds the training data does not use), or "
                              "leave --val-data out")
    episodes = None
    if args.data is None:
        episodes = synthetic_episodes(args.synthetic, args.camera_resolution)
    summary = train(cfg, episodes=episodes)
    if int(os.environ.get("RANK", "0")) == 0:
        loss = summary["final_loss"].get("total", float("nan"))
        print(f"abm train: {summary['steps']} steps, final loss {loss:.4f}, checkpoint {summary['checkpoint']}")
        curve = run_loss_curves({cfg.method: cfg.out}, Path(cfg.out) / "training_curve.png")
        if curve is not None:
            print(f"abm train: training curve {curve}")
    return 0
