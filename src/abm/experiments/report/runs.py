"""What a run folder tells the report: its training log's steps, minutes and speed, and its ``config.json``."""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from abm.train.config import TrainConfig
from abm.train.early_stop import FlatStop


def training_summary(run_dir: Path) -> dict[str, float] | None:
    """Steps, minutes and mean samples/s of a run folder's log (``None`` before its first row)."""
    log = run_dir / "log.csv"
    if not log.is_file():
        return None
    with log.open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    last = rows[-1]
    sps = [float(r["samples_per_s"]) for r in rows[1:]] or [float(last["samples_per_s"])]
    return {"steps": int(last["step"]), "elapsed_min": float(last["elapsed_s"]) / 60,
            "samples_per_s": sum(sps) / len(sps)}


def minutes_at_steps(run_dir: Path, steps: Sequence[int]) -> dict[str, float]:
    """Training minutes when the run's log reached each of ``steps`` (``{"1000": 25.3}``)."""
    log = run_dir / "log.csv"
    if not steps or not log.is_file():
        return {}
    with log.open() as f:
        at = {int(r["step"]): float(r["elapsed_s"]) / 60 for r in csv.DictReader(f)}
    return {str(s): round(at[s], 1) for s in steps if s in at}


def describe_run(run_dir: Path) -> dict[str, Any]:
    """What only a run folder knows (``config.json``, ``log.csv``): tasks, data, steps, recipe, language,
    grounder and training minutes (the steps it trained: fewer than its option when it stopped early, its curve
    flat); ``{}`` when the folder is gone (a fresh clone). The options are read as
    training saved them (:meth:`abm.train.config.TrainConfig.from_dict`, any abm version's form); the learning
    rate is the one the run used (``config.json``'s ``lr``: the option, or the rate it derived)."""
    cfg_path = run_dir / "config.json"
    if not cfg_path.is_file():
        return {}
    cfg = json.loads(cfg_path.read_text())
    train = TrainConfig.from_dict(cfg["train"])
    policy = train.policy
    stopped = FlatStop.from_record(cfg)  # ended early, its curve flat: the steps it trained
    entry: dict[str, Any] = {
        "tasks": train.tasks, "data": str(train.data), "steps": train.steps if stopped is None else stopped.step,
        "recipe": {"batch": train.batch, "optimizer": train.optimizer, "warmup": train.warmup,
                   "weight_decay": train.weight_decay, "seed": train.seed, "lr": cfg["lr"],
                   "resolution": policy.resolution, "patch_size": policy.patch_size, "preset": policy.preset},
        "language": train.language_config.kind, "grounder_spec": train.grounder.to_dict(),
    }
    if policy.workspace_size != 1.0:  # not the default 1 m cube: say so
        entry["recipe"]["workspace_size"] = policy.workspace_size
    if policy.rotation_crop:  # the rotation head also reads a crop (PolicyConfig.rotation_crop)
        entry["recipe"]["rotation_crop"] = policy.rotation_crop
    if policy.zoom_size:  # a zoomed second stage (PolicyConfig.zoom_size)
        entry["recipe"] |= {"zoom_size": policy.zoom_size, "zoom_resolution": policy.zoom_resolution,
                            "zoom_patch_size": policy.zoom_patch_size}
    trained = training_summary(run_dir)
    if trained is not None:
        entry["train_minutes"] = round(trained["elapsed_min"], 1)
    return entry
