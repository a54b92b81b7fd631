"""The options of one training run: :class:`TrainConfig`, which also defines the ``abm train`` flags
(:mod:`abm.configuration`) and is saved with every run (``config.json``) and checkpoint.

The network's configuration is a typed :class:`~abm.policy.config.PolicyConfig` nested in it (``policy``): on the
command line its fields are the policy flags and ``--set KEY=VALUE``, in recipes and specs the ``policy:`` mapping,
both changes of the ``--preset``'s configuration for the ``--method``. Runs written before it was nested saved those
changes as a flat ``policy_overrides`` mapping, which :meth:`TrainConfig.from_dict` reads too.

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
from abm.policy.config import PolicyConfig
from abm.policy.language_config import (
    LANGUAGES,
    LanguageConfig,
    as_language_config,
    default_language,
    language_config_from_dict,
)
from abm.policy.variants import VARIANTS
from abm.train.early_stop import DEFAULT_TOLERANCE, FlatRule

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
        policy: the network's configuration (:class:`~abm.policy.config.PolicyConfig`): the ``preset``'s for the
            ``method`` with the changes of the policy flags (``--view-resolution 64``, ``--set KEY=VALUE``), a
            recipe's ``policy:`` or a spec's; given as a mapping of such changes, it is built from the preset
            (:func:`preset_policy`). Its variant is ``method``, its preset ``preset`` (``+custom`` when sizes
            changed). ``lang_dim`` is the width of a language encoder whose width is free (the hash encoder's); the
            run's network takes its language encoder's width and the grounder's feature width (``ifd``) when
            it is built, and what ``config.json`` and the checkpoints hold is that network's configuration.
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
        stop_when_flat: end the training early, at a checkpoint, once its curve is flat: the mean logged loss
            (val_total with --val-data, else total) over the last this many steps improved on the mean of the as
            many steps before by less than flat_tolerance (abm.train.early_stop; 1000 for 6000-step runs, chosen on
            the second edition's curves in docs/policy.md; unset: train every step).
        flat_tolerance: the relative improvement under which stop_when_flat's window counts as flat (unset: 0.02).
        flat_after: the first step at which stop_when_flat may stop a run (unset: half of steps).
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
    policy: PolicyConfig = field(default_factory=PolicyConfig, metadata={"cli": False})
    cache_dir: Path | None = None
    camera_names: list[str] | None = field(default=None, metadata={"flag": "--cameras"})
    progress: bool = field(default=True, metadata={
        "off_help": "no progress bar, even on a terminal: plain periodic lines only"})
    compile: bool = False
    bf16: str = field(default="auto", metadata={"choices": ["auto", "on", "off"]})
    verify: bool = field(default=True, metadata={
        "off_help": "skip the episode checksum check: train on the files as they are"})
    stop_when_flat: int | None = None
    flat_tolerance: float | None = field(default=None, metadata={"range": (0.0, 1.0)})
    flat_after: int | None = None

    def __post_init__(self) -> None:
        grounder: object = self.grounder  # a kind name or a dict form is read here (flags, recipes, files)
        if not isinstance(grounder, GrounderConfig):
            self.grounder = as_grounder_config(grounder)  # type: ignore[arg-type]
        language: object = self.language
        if language is not None and not isinstance(language, LanguageConfig):
            self.language = as_language_config(language)  # type: ignore[arg-type]
        policy: object = self.policy
        if isinstance(policy, Mapping):  # changes of the preset (recipes, specs, old runs' policy_overrides)
            self.policy = preset_policy(self.preset, self.method, policy)
        elif policy == PolicyConfig() and (self.method, self.preset) != ("abm", "small"):
            self.policy = preset_policy(self.preset, self.method, {})  # the field's default: the preset's
        elif (self.policy.variant, self.policy.preset.split("+")[0]) != (self.method, self.preset):
            raise ConfigError(f"policy: the network of variant {self.policy.variant} and preset {self.policy.preset}, "
                              f"but method {self.method} and preset {self.preset}: give the same (or leave policy "
                              "out)")

    @property
    def flat_rule(self) -> FlatRule | None:
        """The rule that stops this run when its curve is flat (:attr:`stop_when_flat`), or ``None``."""
        if self.stop_when_flat is None:
            return None
        tolerance = DEFAULT_TOLERANCE if self.flat_tolerance is None else self.flat_tolerance
        return FlatRule(self.stop_when_flat, tolerance, self.steps // 2 if self.flat_after is None else self.flat_after)

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
        data["policy"] = self.policy.to_dict()
        loaded: dict[str, Any] = json.loads(json.dumps(data, default=str))
        return loaded

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainConfig:
        """The options of a ``config.json``'s ``train`` or a checkpoint's ``train_config``, of any abm version: the
        nested form, or the flat one written before the grounder was typed (``grounder`` a kind name with its
        options in ``grounder_options``, ``language`` a kind name, whose ``clip`` read the grounder's options) and
        before the policy was (``policy_overrides``: the changes of the preset). Keys of options abm no longer has
        are left out.

        Raises:
            ValueError: a grounder, language encoder or policy that does not read (unknown kind, options or
                fields).
        """
        values = dict(data)
        changes = values.pop("policy_overrides", None) or {}
        policy = values.get("policy")
        values["policy"] = PolicyConfig.from_dict(dict(policy)) if isinstance(policy, Mapping) else changes
        options = values.pop("grounder_options", None) or {}
        grounder = values.get("grounder", "oracle")
        if isinstance(grounder, str):  # the flat form: the options were the CLIP's (unused by the oracle)
            values["grounder"] = (OracleGrounderConfig() if grounder == "oracle"
                                  else grounder_config_from_dict({"kind": grounder, **options}))
        language = values.get("language")
        if isinstance(language, str):  # the flat form: an encoder with a CLIP read the grounder's options
            values["language"] = language_config_from_dict({"kind": language,
                                                            **(options if LANGUAGES[language].clip else {})})
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**_paths({k: v for k, v in values.items() if k in known}))

    @classmethod
    def from_recipe(cls, recipe: Mapping[str, Any], **fields: Any) -> TrainConfig:
        """The options of a recipe (:meth:`to_recipe`'s form, what ``abm train --config`` reads: option names, the
        grounder and language encoder as kinds with the CLIP as ``clip_model`` / ``clip_device``, the policy's
        changes of the preset under ``policy``), with ``fields`` (options in that form too) replacing its values.
        The values are taken as they are: a recipe file's are checked first (:func:`abm.configuration.check_recipe`).

        Raises:
            ConfigError: an option abm train does not have, a grounder or language encoder that does not read,
                or a policy its checks refuse.
        """
        values = {key.replace("-", "_"): value for key, value in {**recipe, **fields}.items()}
        clip = {name: values.pop(f"clip_{name}", None) for name in ("model", "device")}
        kinds = values.pop("grounder", None) or "oracle", values.pop("language", None)
        grounder, language = grounding_from_flags(*kinds, clip["model"], clip["device"])
        unknown = sorted(set(values) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ConfigError(f"unknown option(s) {', '.join(unknown)}")
        return cls(**_paths(values), grounder=grounder, language=language)

    def with_clip(self, model: str) -> TrainConfig:
        """These options with the CLIP weights ``model`` in the grounder and the language encoder that use a CLIP
        (``--clip-model``: :func:`grounding_from_flags`; their other options, which no flag sets, return to their
        defaults).

        Raises:
            ConfigError: neither uses a CLIP.
        """
        grounder, language = grounding_from_flags(self.grounder.kind, None if self.language is None
                                                  else self.language.kind, model)
        return dataclasses.replace(self, grounder=grounder, language=language)

    def to_recipe(self) -> dict[str, Any]:
        """These options as a recipe (``abm train --config FILE``), that is as the flags that set them: every set
        option but the run controls (:data:`RUN_CONTROL`: the run folder, resuming, logging, checks, caches), the
        grounder and language encoder as their kinds with the CLIP as ``clip_model`` / ``clip_device`` (other
        grounder options have no flag, and are left out), the policy's changes of the preset under ``policy``
        (:meth:`~abm.policy.config.PolicyConfig.preset_changes`). Every run writes its own to ``RUN/recipe.yaml``."""
        data = self.to_dict()
        recipe: dict[str, Any] = {}
        for key, value in data.items():
            if key == "grounder":
                recipe[key] = self.grounder.kind
            elif key == "language" and self.language is not None:
                recipe[key] = self.language.kind
            elif value is not None and key not in (*RUN_CONTROL, "language", "policy"):
                recipe[key] = value
        clip = {**self.language_config.clip_options(), **self.grounder.clip_options()}
        recipe.update({f"clip_{k}": v for k, v in clip.items()})
        changes = self.policy.preset_changes()
        if changes:
            recipe["policy"] = changes
        return recipe


def _paths(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` of :class:`TrainConfig` fields with the text of its path fields as paths."""
    hints = typing.get_type_hints(TrainConfig)
    return {name: Path(value) if isinstance(value, str) and Path in (hints[name], *typing.get_args(hints[name]))
            else value for name, value in values.items()}


def preset_policy(preset: str, method: str, changes: Mapping[str, Any]) -> PolicyConfig:
    """The :class:`~abm.policy.config.PolicyConfig` of ``preset`` for the variant ``method`` with the fields
    ``changes`` names set (:meth:`~abm.policy.config.PolicyConfig.from_preset`).

    Raises:
        ConfigError: a field the policy does not have, or values its checks refuse (a patch that does not divide
            the view resolution, ...).
    """
    unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(PolicyConfig)})
    if unknown:
        raise ConfigError(f"policy: unknown field(s) {', '.join(unknown)}")
    try:
        return PolicyConfig.from_preset(preset, method, **changes)
    except (TypeError, ValueError) as err:  # PolicyConfig's checks of the values it is given
        raise ConfigError(f"policy: {err}") from None


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
