"""The options of one training run: :class:`TrainConfig`, which also defines the ``abm train`` flags
(:mod:`abm.configuration`) and is saved with every run (``config.json``) and checkpoint."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from abm.policy.variants import VARIANTS


@dataclass
class TrainConfig:
    """Options of one training run (the ``abm train`` flags).

    Attributes:
        method: policy variant (``abm``, ``rvt``, ``ifd``, ``stack``, ``concat-rerendered``, ``concat-full``).
        preset: model size preset (``small``, ``paper``).
        out: run folder.
        data: episode store folder (from ``abm data generate``; ``None`` when episodes are passed in memory).
        tasks: tasks to train on (default: all in the store).
        splits: episode splits to use.
        steps: total optimiser steps.
        batch: samples per step *per process*.
        lr: peak learning rate (default ``1e-4 * batch * world_size``; the paper used 0.003 at batch 30).
        optimizer: ``lamb`` (the paper's choice, ``torch_optimizer.Lamb``) or ``adamw`` (converges much
            faster in short CPU runs: LAMB's per-layer trust ratio makes updates of small-norm layers,
            such as the heatmap decoder's output, tiny at first).
        warmup: linear warm-up steps (default ``min(2000, steps // 20)``).
        min_lr_ratio: the cosine decays to ``lr * min_lr_ratio``.
        weight_decay: optimiser weight decay.
        grad_clip: max global gradient norm (0 = off).
        checkpoint_every: steps between checkpoints (also one at the end).
        keep_checkpoints: periodic checkpoints kept (0 = all).
        log_every: steps between log rows.
        workers: DataLoader worker processes.
        device: ``cpu``, ``cuda`` or ``cuda:N`` (under torchrun CUDA uses ``cuda:LOCAL_RANK``).
        grounder: target-object grounding (``oracle`` or ``clip``); options in ``grounder_options``.
        grounder_options: options of the grounder (``abm train``: ``--clip-model``, ``--clip-device``).
        language: language encoder (``hash`` or ``clip``; default: ``clip`` with the clip grounder, else ``hash``).
        seed: seed of model init and the data stream.
        resume: continue from the latest checkpoint in ``out`` (from scratch if it has none).
        accept_changed_config: with ``resume``, continue even though options that shape the optimisation
            (learning rate, batch, seed, ...) differ from the checkpoint's; the new values are used and
            ``config.json`` lists what changed (without it such a resume is refused).
        overwrite: replace a run already in ``out`` (without it, and without ``resume``, a folder that
            holds a run is refused, so no run is lost).
        augment: SE(3) augmentation of the scene and the action (``--no-augment`` turns it off).
        policy_overrides: ``PolicyConfig`` field overrides (``abm train --set resolution=64``).
        cache_dir: grounding / CLIP feature cache (default ``out/cache``).
        camera_names: cameras to fuse (default all).
        progress: show a progress bar (``--no-progress`` hides it).
        verify: check the checksums of every episode before training (each file is read in full once, then
            only when it changes; ``--no-verify`` trains on the files as they are).
    """

    method: str = field(default="abm", metadata={"choices": sorted(VARIANTS), "required": True})
    preset: str = field(default="small", metadata={"choices": ["small", "paper"]})
    out: Path = field(default=Path("runs/policy"), metadata={"required": True})
    data: Path | None = None
    tasks: list[str] | None = None
    splits: list[str] | None = field(default_factory=lambda: ["seen"])
    steps: int = field(default=1000, metadata={"required": True})
    batch: int = 8
    lr: float | None = None
    optimizer: str = field(default="lamb", metadata={"choices": ["lamb", "adamw"]})
    warmup: int | None = None
    min_lr_ratio: float = 0.0
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    checkpoint_every: int = 1000
    keep_checkpoints: int = 3
    log_every: int = 10
    workers: int = 0
    device: str = "cpu"
    grounder: str = field(default="oracle", metadata={"choices": ["oracle", "clip"]})
    grounder_options: dict[str, Any] = field(default_factory=dict, metadata={"cli": False})
    language: str | None = field(default=None, metadata={"choices": ["hash", "clip"]})
    seed: int = 0
    resume: bool = False
    accept_changed_config: bool = False
    overwrite: bool = False
    augment: bool = True
    policy_overrides: dict[str, Any] = field(default_factory=dict, metadata={"cli": False})
    cache_dir: Path | None = None
    camera_names: list[str] | None = field(default=None, metadata={"flag": "--cameras"})
    progress: bool = True
    verify: bool = True

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self), default=str))
