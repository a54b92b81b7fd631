"""The options of one training run: :class:`TrainConfig`, which also defines the ``abm train`` flags
(:mod:`abm.configuration`) and is saved with every run (``config.json``) and checkpoint."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abm.policy.variants import VARIANTS

if TYPE_CHECKING:
    from abm.grounding.config import GrounderConfig


#: options that control a run, not what it trains: left out of the recipe a run writes (RUN/recipe.yaml), so a
#: recipe reused for another run never resumes, overwrites, skips checks or shares a cache by accident
RUN_CONTROL = ("out", "resume", "accept_changed_config", "overwrite", "progress", "verify", "cache_dir", "log_every",
               "keep_checkpoints", "workers")


@dataclass
class TrainConfig:
    """Options of one training run (the ``abm train`` flags). The defaults are the measured CPU recipe
    (docs/policy.md): AdamW, lr 1e-3, 50 warm-up steps, batch 8 (``configs/cpu.yaml`` adds its 64-pixel views).

    Attributes:
        method: policy variant (``abm``, ``rvt``, ``ifd``, ``stack``, ``concat-rerendered``, ``concat-full``).
        preset: model size preset (``small``, ``paper``).
        out: run folder.
        data: episode store folder (from ``abm data generate``; ``None`` when episodes are passed in memory).
        tasks: tasks to train on (default: all in the store).
        splits: episode splits to use.
        val_data: episode store of held-out demonstrations (same tasks, other scenes): their loss (no
            augmentation) is logged at every checkpoint and at the end (``val_total`` in log.csv).
        steps: total optimiser steps.
        batch: samples per step *per process*.
        lr: peak learning rate (the measured CPU recipe's; the paper used LAMB at 0.003 for batch 30).
        optimizer: ``adamw`` (the measured CPU recipe: converges much faster in short CPU runs) or ``lamb``
            (the paper's choice, ``torch_optimizer.Lamb``; its per-layer trust ratio makes updates of
            small-norm layers, such as the heatmap decoder's output, tiny at first).
        warmup: linear warm-up steps.
        min_lr_ratio: the cosine decays to ``lr * min_lr_ratio``.
        weight_decay: optimiser weight decay.
        grad_clip: max global gradient norm (0 = off).
        checkpoint_every: steps between checkpoints (also one at the end).
        keep_checkpoints: periodic checkpoints kept (0 = all).
        log_every: steps between log rows.
        workers: DataLoader worker processes.
        device: ``cpu``, ``cuda`` or ``cuda:N`` (under torchrun CUDA uses ``cuda:LOCAL_RANK``).
        grounder: target-object grounding (``oracle`` or ``clip``); options in ``grounder_options``.
        grounder_options: options of the grounder (``abm train``: ``--clip-model``, ``--clip-device``); the run
            uses them as the typed :attr:`grounder_config`.
        language: language encoder (``hash`` or ``clip``; default: ``clip`` with the clip grounder, else ``hash``).
        seed: seed of model init and the data stream.
        resume: continue from the latest checkpoint in ``out`` (from scratch if it has none).
        accept_changed_config: with ``resume``, continue even though options that shape the optimisation
            (learning rate, batch, seed, ...) differ from the checkpoint's; the new values are used and
            ``config.json`` lists what changed (without it such a resume is refused).
        overwrite: replace a run already in ``out`` (without it, and without ``resume``, a folder that
            holds a run is refused, so no run is lost).
        augment: SE(3) augmentation of the scene and the action.
        policy_overrides: ``PolicyConfig`` field overrides (``abm train --set resolution=64``).
        cache_dir: grounding / CLIP feature cache (default ``out/cache``).
        camera_names: cameras to fuse (default all).
        progress: a progress bar on a terminal (plain periodic lines when the output is a file or pipe).
        compile: run the network through ``torch.compile`` (measured 0.44 -> 0.39 s per step at 64² views on
            2 CPU threads after a ~50 s compile: worth it for runs of more than a few hundred steps).
        bf16: bf16 autocast on CPU: ``auto`` (float32 on the CPU: measured faster than bf16 autocast for this
            network, also where oneDNN reports native bf16), ``on`` or ``off``. CUDA always trains under bf16
            autocast.
        verify: check the checksums of every episode before training (each file is read in full once, then
            only when it changes; ``--no-verify`` trains on the files as they are).
    """

    method: str = field(default="abm", metadata={"choices": sorted(VARIANTS), "required": True})
    preset: str = field(default="small", metadata={"choices": ["small", "paper"]})
    out: Path = field(default=Path("runs/policy"), metadata={"required": True})
    data: Path | None = None
    tasks: list[str] | None = None
    splits: list[str] | None = field(default_factory=lambda: ["seen"])
    val_data: Path | None = None
    steps: int = field(default=1000, metadata={"required": True})
    batch: int = 8
    lr: float | None = 1e-3
    optimizer: str = field(default="adamw", metadata={"choices": ["adamw", "lamb"]})
    warmup: int | None = 50
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
    augment: bool = field(default=True, metadata={"off_help": "no SE(3) augmentation of the scene and the action"})
    policy_overrides: dict[str, Any] = field(default_factory=dict, metadata={"cli": False})
    cache_dir: Path | None = None
    camera_names: list[str] | None = field(default=None, metadata={"flag": "--cameras"})
    progress: bool = field(default=True, metadata={
        "off_help": "no progress bar, even on a terminal: plain periodic lines only"})
    compile: bool = False
    bf16: str = field(default="auto", metadata={"choices": ["auto", "on", "off"]})
    verify: bool = field(default=True, metadata={
        "off_help": "skip the episode checksum check: train on the files as they are"})

    @property
    def grounder_config(self) -> GrounderConfig:
        """The typed grounder configuration of ``grounder`` + ``grounder_options`` (the two fields are its
        form in flags, recipes and ``config.json``); unknown options raise ``ValueError``."""
        from abm.grounding.config import OracleGrounderConfig, grounder_config_from_dict  # torch: not at --help

        if self.grounder == "oracle":
            return OracleGrounderConfig()
        return grounder_config_from_dict({"kind": self.grounder, **self.grounder_options})

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self), default=str))

    def to_recipe(self) -> dict[str, Any]:
        """These options as a recipe (``abm train --config FILE``): every set option but the run controls
        (:data:`RUN_CONTROL`: the run folder, resuming, logging, checks, caches), policy overrides under
        ``policy``, the CLIP options as ``clip_model`` / ``clip_device``. Every run writes its own to
        ``RUN/recipe.yaml``."""
        data = self.to_dict()
        recipe = {k: v for k, v in data.items() if v is not None and k not in (
            *RUN_CONTROL, "grounder_options", "policy_overrides")}
        recipe.update({f"clip_{k}": v for k, v in data["grounder_options"].items() if k in ("model", "device")})
        if data["policy_overrides"]:
            recipe["policy"] = data["policy_overrides"]
        return recipe
