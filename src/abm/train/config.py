"""The options of one training run: :class:`TrainConfig`, which also defines the ``abm train`` flags
(:mod:`abm.configuration`) and is saved with every run (``config.json``) and checkpoint.

The grounder and the language encoder are typed configurations nested in it
(:class:`~abm.grounding.config.GrounderConfig`, :class:`~abm.policy.language_config.LanguageConfig`); on the command
line and in recipes they are ``--grounder KIND``, ``--language KIND`` and the CLIP's ``--clip-model`` /
``--clip-device`` (:func:`grounding_from_flags`). Files hold the nested dict form; :meth:`TrainConfig.from_dict`
also reads the flat form runs wrote before (``grounder: clip``, ``grounder_options: {...}``, ``language: null``).
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from abm.errors import ConfigError
from abm.grounding.config import (
    GROUNDERS,
    GrounderConfig,
    OracleGrounderConfig,
    as_grounder_config,
    grounder_config_from_dict,
)
from abm.policy.language_config import (
    LANGUAGES,
    LanguageConfig,
    as_language_config,
    default_language,
    language_config_from_dict,
)
from abm.policy.variants import VARIANTS

#: options that control a run, not what it trains: left out of the recipe a run writes (RUN/recipe.yaml), so a
#: recipe reused for another run never resumes, overwrites, skips checks or shares a cache by accident
RUN_CONTROL = ("out", "resume", "accept_changed_config", "overwrite", "progress", "verify", "cache_dir", "log_every",
               "keep_checkpoints", "workers", "memory_mb")


@dataclass
class TrainConfig:
    """Options of one training run (the ``abm train`` flags). The defaults are the measured CPU recipe
    (docs/policy.md): AdamW, lr 1e-3, 50 warm-up steps, batch 8 (``configs/cpu.yaml`` adds its 64-pixel views).

    Attributes:
        method: policy variant (its name in abm.policy.variants.VARIANTS).
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
        memory_mb: MiB (per data process) for keyframes kept fused and grounded between their draws; only the
            augmentation is redone (0 = recompute every draw; samples are identical either way).
        device: ``cpu``, ``cuda`` or ``cuda:N`` (under torchrun CUDA uses ``cuda:LOCAL_RANK``).
        grounder: target-object grounding: oracle or clip, the grounders that ground each frame on its own
            (its CLIP: --clip-model, --clip-device); in files and in Python, its configuration
            (abm.grounding.config).
        language: language encoder: hash (weight-free) or clip (the CLIP's text tokens; default: the clip
            grounder's own CLIP, else hash: language_config); in files and in Python, its configuration
            (abm.policy.language_config).
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

    method: str = field(default="abm", metadata={"choices": VARIANTS.names, "required": True})
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
    memory_mb: float = 2048.0
    device: str = "cpu"
    grounder: GrounderConfig = field(default_factory=OracleGrounderConfig,
                                     metadata={"choices": lambda: GROUNDERS.names(per_frame=True)})
    language: LanguageConfig | None = field(default=None, metadata={"choices": LANGUAGES.names})
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

    def __post_init__(self) -> None:
        grounder: object = self.grounder  # a kind name or a dict form is read here (flags, recipes, files)
        if not isinstance(grounder, GrounderConfig):
            self.grounder = as_grounder_config(grounder)  # type: ignore[arg-type]
        language: object = self.language
        if language is not None and not isinstance(language, LanguageConfig):
            self.language = as_language_config(language)  # type: ignore[arg-type]

    @property
    def language_config(self) -> LanguageConfig:
        """The language encoder the run uses: :attr:`language`, else the grounder's default
        (:func:`abm.policy.language_config.default_language`)."""
        return self.language if self.language is not None else default_language(self.grounder)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``config.json``'s ``train``, checkpoints' ``train_config``): the grounder and the
        language encoder as their dict forms, paths as text."""
        data: dict[str, Any] = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        data["grounder"] = self.grounder.to_dict()
        data["language"] = None if self.language is None else self.language.to_dict()
        loaded: dict[str, Any] = json.loads(json.dumps(data, default=str))
        return loaded

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainConfig:
        """The options of a ``config.json``'s ``train`` or a checkpoint's ``train_config``, of any abm version: the
        nested form, or the flat one written before the grounder was typed (``grounder`` a kind name with its
        options in ``grounder_options``, ``language`` a kind name, whose ``clip`` read the grounder's options).
        Keys of options abm no longer has are left out.

        Raises:
            ValueError: a grounder or language encoder that does not read (unknown kind or options).
        """
        values = dict(data)
        options = values.pop("grounder_options", None) or {}
        grounder = values.get("grounder", "oracle")
        if isinstance(grounder, str):  # the flat form: the options were the CLIP's (unused by the oracle)
            values["grounder"] = (OracleGrounderConfig() if grounder == "oracle"
                                  else grounder_config_from_dict({"kind": grounder, **options}))
        language = values.get("language")
        if isinstance(language, str):  # the flat form: the clip encoder read the grounder's options
            values["language"] = language_config_from_dict({"kind": language,
                                                            **(options if language == "clip" else {})})
        hints = typing.get_type_hints(cls)
        known = {f.name for f in dataclasses.fields(cls)}
        for name in known & set(values):
            if Path in typing.get_args(hints[name]) + (hints[name],) and isinstance(values[name], str):
                values[name] = Path(values[name])
        return cls(**{k: v for k, v in values.items() if k in known})

    def to_recipe(self) -> dict[str, Any]:
        """These options as a recipe (``abm train --config FILE``), that is as the flags that set them: every set
        option but the run controls (:data:`RUN_CONTROL`: the run folder, resuming, logging, checks, caches), the
        grounder and language encoder as their kinds with the CLIP as ``clip_model`` / ``clip_device`` (other
        grounder options have no flag, and are left out), policy overrides under ``policy``. Every run writes its
        own to ``RUN/recipe.yaml``."""
        data = self.to_dict()
        recipe: dict[str, Any] = {}
        for key, value in data.items():
            if key == "grounder":
                recipe[key] = self.grounder.kind
            elif key == "language" and self.language is not None:
                recipe[key] = self.language.kind
            elif value is not None and key not in (*RUN_CONTROL, "language", "policy_overrides"):
                recipe[key] = value
        clip = {**self.language_config.clip_options(), **self.grounder.clip_options()}
        recipe.update({f"clip_{k}": v for k, v in clip.items()})
        if data["policy_overrides"]:
            recipe["policy"] = data["policy_overrides"]
        return recipe


def grounding_from_flags(grounder: str, language: str | None = None, clip_model: str | None = None,
                         clip_device: str | None = None) -> tuple[GrounderConfig, LanguageConfig | None]:
    """The typed grounder and language encoder of ``abm train --grounder KIND [--language KIND] [--clip-model M]
    [--clip-device D]``: the CLIP weights go to each of the two that uses a CLIP (so ``--grounder clip --clip-model
    M`` trains with M's masks and, with no ``--language``, M's text tokens; ``--grounder oracle --language clip
    --clip-model M`` with M's text tokens only).

    Raises:
        ValueError: an unknown kind, or CLIP weights given where neither uses a CLIP.
    """
    ground = grounder_config_from_dict({"kind": grounder})
    lang = None if language is None else language_config_from_dict({"kind": language})
    if clip_model is None and clip_device is None:
        return ground, lang
    ground = ground.with_clip(clip_model, clip_device) or ground
    with_clip = lang.with_clip(clip_model, clip_device) if lang is not None else None
    if not ground.clip_options() and with_clip is None:
        clip_grounders = " or ".join(f"--grounder {name}" for name in GROUNDERS.names(per_frame=True, clip=True))
        clip_languages = " or ".join(f"--language {name}" for name in LANGUAGES.names(clip=True))
        raise ConfigError(f"--clip-model/--clip-device need {clip_grounders} or {clip_languages}")
    return ground, with_clip or lang
