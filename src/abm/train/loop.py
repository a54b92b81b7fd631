"""Behaviour-cloning training loop for every policy variant (single process or ``torchrun`` DDP).

* AdamW (default) or LAMB (``torch_optimizer.Lamb``), linear warm-up then cosine decay, gradient-norm clipping,
  bf16 autocast on CUDA (on CPU only with ``--bf16 on``), optional ``torch.compile``.
* Data: :class:`~abm.data.keyframes.KeyframeDataset` with the deterministic
  :class:`~abm.data.keyframes.StepSampler` (rank-sharded like ``DistributedSampler``), so a run
  resumed from a checkpoint sees exactly the batches the uninterrupted run would have seen.
* Distributed: launched by ``torchrun`` (``WORLD_SIZE`` > 1) the loop joins a process group (gloo on
  CPU, nccl on CUDA) and wraps the model in ``DistributedDataParallel``; rank 0 logs and saves.
* :class:`Trainer` splits a run into build / step / save-restore / fit; :func:`train` runs one.
  Messages go through :mod:`logging` (logger ``abm.train.loop``; the ``abm`` command shows INFO).
* Outputs in the run folder: ``config.json``, ``recipe.yaml`` (``abm train --config``), ``log.csv``,
  ``tb/`` (TensorBoard), ``checkpoints/step_XXXXXXXX.pt`` (every ``checkpoint_every`` steps, at the end,
  and on Ctrl-C or SIGTERM), ``summary.json``.
"""

from __future__ import annotations

import csv
import gc
import hashlib
import json
import logging
import math
import os
import random
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist

from abm.data.episode_store import EpisodeStore, check_episodes
from abm.data.keyframes import (
    EpisodeSource,
    KeyframeDataset,
    StepSampler,
    check_inside_workspace,
    collate,
    ground_keyframes,
    worker_init,
)
from abm.errors import CheckpointError, ConfigError, DataError, ExternalError, OutputError
from abm.files import FolderLock, refuse_links, write_text_atomic
from abm.grounding.config import GROUNDERS, ClipGrounderConfig, build_grounder
from abm.policy.checkpoint import (
    checkpoint_path,
    list_checkpoints,
    load_checkpoint,
    prune_checkpoints,
    save_checkpoint,
)
from abm.policy.config import PolicyConfig, check_compatible
from abm.policy.keyframe_policy import LOSS_TERMS, KeyframePolicy
from abm.policy.language_config import build_language_encoder
from abm.progress import Progress
from abm.train.config import TrainConfig
from abm.train.early_stop import FlatStop
from abm.train.stop import StopOnTerm
from abm.types import Episode

log = logging.getLogger(__name__)

LOG_FIELDS = ("step", "lr", "total", "translation", "rotation", "gripper", "collision", "val_total",
              "samples_per_s", "elapsed_s", "zoom_translation")
VAL_SAMPLES = 64  # held-out keyframes per validation loss (the first ones, the same every time)


@dataclass
class DistInfo:
    world_size: int = 1
    rank: int = 0
    local_rank: int = 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def main(self) -> bool:
        return self.rank == 0


def _setup_distributed(device: str) -> DistInfo:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    info = DistInfo(world, int(os.environ.get("RANK", "0")), int(os.environ.get("LOCAL_RANK", "0")))
    if not dist.is_initialized():
        backend = "nccl" if device.startswith("cuda") else "gloo"
        dist.init_process_group(backend=backend)
    return info


def make_optimizer(name: str, params: Iterable[torch.nn.Parameter], lr: float, weight_decay: float
                   ) -> torch.optim.Optimizer:
    """``lamb`` (``torch_optimizer.Lamb``, the paper's) or ``adamw``.

    AdamW runs its fused kernel where torch has one (parameters on the CPU or CUDA): the same update as the
    per-tensor loop within float rounding (~3e-8 after 5 steps), 3.5x faster on the CPU (7 against 26 ms a step
    for the 2-million-parameter two-stage small policy at one thread; docs/performance.md)."""
    if name == "lamb":
        from torch_optimizer import Lamb

        return Lamb(params, lr=lr, weight_decay=weight_decay)
    if name == "adamw":
        params = list(params)
        return torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay, fused=_fusable(params) or None)
    raise ValueError(f"unknown optimizer {name!r}; choose 'lamb' or 'adamw'")


def _fusable(params: Sequence[torch.nn.Parameter | dict[str, Any]]) -> bool:
    """Whether torch's fused AdamW takes these parameters (or parameter groups): floating point on CPU or CUDA."""
    tensors = [t for p in params for t in (p["params"] if isinstance(p, dict) else [p])]
    return bool(tensors) and all(t.device.type in ("cpu", "cuda") and t.is_floating_point() for t in tensors)


def use_fused_adamw(optimizer: torch.optim.Optimizer) -> None:
    """After ``load_state_dict``: run a restored AdamW with the fused kernel again (a checkpoint's parameter groups
    carry the ``fused`` flag of the optimiser that saved them, ``None`` for one from before it was used)."""
    if not isinstance(optimizer, torch.optim.AdamW):
        return
    fused = _fusable(optimizer.param_groups) or None
    for group in optimizer.param_groups:
        group["fused"] = fused
        if fused:
            group["foreach"] = None


def _lr_lambda(warmup: int, total: int, min_ratio: float) -> Callable[[int], float]:
    def f(step: int) -> float:
        if warmup > 0 and step < warmup:
            return (step + 1) / warmup
        progress = min(max(step - warmup, 0) / max(total - warmup, 1), 1.0)
        return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return f


def _rng_state() -> dict[str, Any]:
    numpy_state = np.random.get_state(legacy=True)  # noqa: NPY002
    assert isinstance(numpy_state, tuple)  # the global generator is a MT19937: its legacy tuple
    state = {
        "torch": torch.get_rng_state(),
        # as (name, tensor, pos, has_gauss, cached) so checkpoints load with weights_only=True
        "numpy": _numpy_state_plain(numpy_state),
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _numpy_state_plain(state: tuple[str, np.ndarray, int, int, float]) -> tuple[str, torch.Tensor, int, int, float]:
    name, keys, pos, has_gauss, cached = state
    return str(name), torch.from_numpy(np.asarray(keys, np.int64)), int(pos), int(has_gauss), float(cached)


def _set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((name, np.asarray(keys, np.uint32), int(pos), int(has_gauss), float(cached)))  # noqa: NPY002
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def parameter_digest(model: torch.nn.Module) -> str:
    """SHA-1 of all parameters (bytes), to compare models across ranks or runs."""
    h = hashlib.sha1()
    for _, p in sorted(model.state_dict().items()):
        h.update(p.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def build_policy_config(cfg: TrainConfig, lang_dim: int, feature_dim: int | None) -> PolicyConfig:
    """The run's network: :attr:`TrainConfig.policy` with the language encoder's width ``lang_dim`` and, for a
    variant fed CLIP point features, the grounder's feature width ``feature_dim``."""
    policy = replace(cfg.policy, lang_dim=lang_dim)
    return policy if feature_dim is None else replace(policy, ifd_feature_dim=feature_dim)


def language_spec(cfg: TrainConfig, lang_dim: int) -> dict[str, Any]:
    """The run's language encoder in its checkpoint form (:attr:`TrainConfig.language_config`, a free width set to
    ``lang_dim``)."""
    return cfg.language_config.with_width(lang_dim).to_dict()


def _episode_source(cfg: TrainConfig, episodes: Sequence[Episode] | None, data: Path | None = None,
                    splits: list[str] | None = None) -> EpisodeSource:
    if episodes is not None:
        return EpisodeSource(list(episodes))
    data, splits = (data, splits) if data is not None else (cfg.data, cfg.splits)
    if data is None:
        raise ConfigError("no training data: give --data DIR (an episode store) or --synthetic N")

    store = EpisodeStore(data)
    indices = store.select(tasks=cfg.tasks, splits=splits)
    if not indices:
        raise ConfigError(store.nothing_selected(cfg.tasks, splits))
    store.check_consistent(indices)
    if cfg.verify:
        bad = check_episodes([store.episodes[i].path for i in indices], cfg.data)
        if bad:
            shown = "; ".join(reason for _, reason in bad[:3]) + (f"; and {len(bad) - 3} more" if len(bad) > 3 else "")
            raise DataError(f"{len(bad)} episode file(s) in {cfg.data} fail verification: {shown}. Run abm data "
                            "generate again with the same arguments (it re-creates them), or pass --no-verify "
                            "to train on them anyway")
    return EpisodeSource(store, indices)


class _Logger:
    """CSV + TensorBoard logging on rank 0; truncates rows past the resume step."""

    def __init__(self, run: Path, start_step: int, enabled: bool) -> None:
        self.enabled = enabled
        self.tb = None
        self.rows: list[dict[str, str]] = []  # every row of log.csv, as text (rank 0)
        if not enabled:
            return
        self.path = run / "log.csv"
        rows = []
        if self.path.exists() and start_step > 0:
            with self.path.open() as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= start_step]
        with self.path.open("w", newline="") as f:
            w = csv.DictWriter(f, LOG_FIELDS)
            w.writeheader()
            w.writerows(rows)
        self.rows = rows
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(run / "tb"), purge_step=start_step + 1 if start_step else None)
        except ImportError:  # tensorboard is optional
            self.tb = None

    def log(self, row: dict[str, float | str]) -> None:
        if not self.enabled:
            return
        text = {k: str(row.get(k, "")) for k in LOG_FIELDS}
        self.rows.append(text)
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, LOG_FIELDS).writerow(text)
        if self.tb is not None:
            step = int(row["step"])
            for k in ("total", "translation", "rotation", "gripper", "collision", "zoom_translation"):
                self.tb.add_scalar(f"loss/{k}", row[k], step)
            self.tb.add_scalar("lr", row["lr"], step)
            self.tb.add_scalar("samples_per_s", row["samples_per_s"], step)
            if row.get("val_total", "") != "":
                self.tb.add_scalar("loss/val_total", row["val_total"], step)

    def curve(self, loss: str) -> list[tuple[int, float]]:
        """``(step, value)`` of the column ``loss`` in the rows that have it."""
        return [(int(r["step"]), float(r[loss])) for r in self.rows if r.get(loss, "") != ""]

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


_RUN_FILES = ("config.json", "log.csv", "summary.json")

# Options that shape the optimisation: ``--resume`` keeps them unless told otherwise (``--steps`` may grow; the
# model's own options are checked by ``check_compatible``; the rest - paths, devices, logging - may change).
RESUME_FIXED = ("tasks", "splits", "batch", "lr", "optimizer", "warmup", "min_lr_ratio", "weight_decay", "grad_clip",
                "grounder", "language", "seed", "augment", "camera_names")


def changed_settings(saved: dict[str, Any], cfg: TrainConfig) -> dict[str, tuple[Any, Any]]:
    """``{option: (value in the checkpoint, value now)}`` of the :data:`RESUME_FIXED` options that differ.

    ``saved`` is a checkpoint's ``train_config`` in any abm version's form (:meth:`TrainConfig.from_dict`); the
    grounder and the language encoder are compared by what they mean (typed: a default named or left out is the
    same option; the language encoder as the run uses it, also when it follows the grounder), and shown in their
    dict form."""
    if not saved:
        return {}
    try:
        old = TrainConfig.from_dict(saved)
    except ValueError:  # a grounder this version cannot read: everything about it differs
        old = None
    before, now = (old.to_dict() if old is not None else dict(saved)), cfg.to_dict()
    changed = {}
    for key in RESUME_FIXED:
        if key not in saved:  # written before the option existed
            continue
        if old is None:
            same = saved[key] == now[key]
        elif key == "language":
            same = old.language_config == cfg.language_config
        else:
            same = getattr(old, key) == getattr(cfg, key)
        if not same:
            changed[key] = (before[key], now[key])
    return changed


def _check_same_data(run: Path, saved: dict[str, Any], cfg: TrainConfig) -> None:
    """``--resume`` continues a run on the episodes it was trained on: another ``--data`` is refused (the
    sampler's batch order, the verified-episode record and the run's meaning all belong to that store)."""
    if "data" not in saved:  # a checkpoint written before the options were saved with it
        return
    old, new = saved["data"], cfg.data
    same = (old is None and new is None) or (
        old is not None and new is not None and Path(old).expanduser().resolve() == Path(new).expanduser().resolve())
    if not same:
        was = f"--data {old}" if old is not None else "in-memory episodes (no --data)"
        now = f"--data {new}" if new is not None else "no --data"
        raise ConfigError(f"{run} was trained on {was}; --resume continues a run on the same episodes, not on "
                          f"{now}: resume with the same --data, or train into a new --out folder")


# What abm train (and abm train's training curve) writes or deletes in a run folder: none may be a symbolic link,
# or the write (a truncating ``open``, an ``--overwrite``) would land on the link's target, outside the run.
RUN_FOLDER_ENTRIES = ("config.json", "recipe.yaml", "log.csv", "summary.json", "training_curve.png", "tb",
                      "checkpoints", "checkpoints/*", "cache")


def _claim_run_folder(run: Path, cfg: TrainConfig, dinfo: DistInfo) -> None:
    """Refuse to train into a folder that holds another run, unless resuming or told to overwrite."""
    existing = list_checkpoints(run)
    occupied = bool(existing) or any((run / name).exists() for name in _RUN_FILES)
    if occupied and not cfg.resume:
        if not cfg.overwrite:
            at = f" (checkpoint at step {existing[-1][0]})" if existing else ""
            raise OutputError(f"{run} already holds a training run{at}: continue it with --resume, train into a "
                              "new --out folder, or pass --overwrite to replace it")
        if dinfo.main:
            for _, path in existing:
                path.unlink(missing_ok=True)
            for name in _RUN_FILES:
                (run / name).unlink(missing_ok=True)
            shutil.rmtree(run / "tb", ignore_errors=True)
    if dinfo.enabled:
        dist.barrier()  # every rank has checked before rank 0 writes the new run's files
    run.mkdir(parents=True, exist_ok=True)


class Trainer:
    """One training run: :meth:`build` (distributed setup, run folder, policy, data, optimiser, resume
    state), :meth:`step` (one optimiser step), :meth:`save` / :meth:`restore` (checkpoints) and
    :meth:`fit` (the loop with logging, progress and checkpoints).

    Args:
        cfg: run options.
        episodes: in-memory episodes (instead of ``cfg.data``).
    """

    def __init__(self, cfg: TrainConfig, episodes: Sequence[Episode] | None = None) -> None:
        self.cfg = cfg
        self.episodes = episodes
        self.run = Path(cfg.out)
        self.start = 0
        self.prior_s = 0.0  # training seconds of earlier sessions of this run (resumes)
        self.changed: dict[str, tuple[Any, Any]] = {}  # settings changed on resume (--accept-changed-config)
        self._t0 = time.perf_counter()
        self.term = StopOnTerm()  # installed while fit() runs: SIGTERM stops at a step boundary
        self.stop_requested = False  # after a step: a SIGTERM arrived (in any rank when distributed)
        self.stopped: FlatStop | None = None  # the run ended early, its curve flat (cfg.stop_when_flat)

    # ------------------------------------------------------------------ build
    def build(self) -> Trainer:
        """Set everything up; raises ``ValueError`` on bad options before anything is written (and
        :class:`abm.files.LinkError` when a file the run writes is a symbolic link, :data:`RUN_FOLDER_ENTRIES`)."""
        cfg = self.cfg
        refuse_links(self.run, RUN_FOLDER_ENTRIES, fix="remove the link (or train into a new --out folder)")
        self.dinfo = dinfo = _setup_distributed(cfg.device)
        self.device = device = torch.device(cfg.device)
        if device.type == "cuda":
            if not torch.cuda.is_available():
                raise ExternalError("--device cuda requested but CUDA is not available")
            if dinfo.enabled:
                self.device = device = torch.device("cuda", dinfo.local_rank)
            torch.cuda.set_device(device)
        if cfg.resume and cfg.overwrite:
            raise ConfigError("--resume and --overwrite contradict each other: choose one")
        ckpt = self._resume_checkpoint()

        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)  # noqa: NPY002 - global RNG of third-party code
        random.seed(cfg.seed)
        self.language_spec = ckpt["language"] if ckpt is not None else language_spec(cfg, cfg.policy.lang_dim)
        encoder = build_language_encoder(self.language_spec)
        self.grounder_config = gconfig = cfg.grounder
        if not GROUNDERS[gconfig.kind].per_frame:
            raise ConfigError(f"grounder {gconfig.kind!r} carries state from one step of an episode to the next: "
                              f"train with one that grounds each frame ({', '.join(GROUNDERS.names(per_frame=True))})")
        feature_dim = None
        if cfg.policy.spec.clip_features:
            if not isinstance(gconfig, ClipGrounderConfig):
                raise ConfigError(f"method {cfg.method!r} re-renders CLIP features: use --grounder clip")
            g = build_grounder(gconfig)
            feature_dim = getattr(g, "feature_dim", None) or getattr(getattr(g, "backbone", None), "embed_dim", None)
        self.policy_config = build_policy_config(cfg, encoder.dim, feature_dim)
        self.trained = replace(cfg, policy=self.policy_config)  # what config.json and checkpoints hold
        if ckpt is not None:
            try:
                check_compatible(PolicyConfig.from_dict(ckpt["policy_config"]), self.policy_config, ckpt["path"])
            except ValueError as err:  # the message names the checkpoint, each differing field and the fix
                raise CheckpointError(str(err)) from err
        self.policy = KeyframePolicy(self.policy_config, encoder, gconfig, cfg.camera_names).to(device)
        if device.type == "cpu" and self.policy.use_cpu_bf16(cfg.bf16) and dinfo.main:
            log.info("abm train: bf16 autocast on the CPU (--bf16 %s)", cfg.bf16)
        if cfg.compile:
            self.policy.compile_network()
        source = _episode_source(cfg, self.episodes)
        check_inside_workspace(source, self.policy.workspace)  # every rank, before anything is written
        val_source = _episode_source(cfg, None, Path(cfg.val_data)) if cfg.val_data is not None else None
        if val_source is not None:
            check_inside_workspace(val_source, self.policy.workspace)
        _claim_run_folder(self.run, cfg, dinfo)  # options are valid: now the folder may be written
        self.dataset = self._dataset(source)
        self.val_dataset = self._dataset(val_source, augment=False) if val_source is not None else None
        self.episodes_used = len(source.indices)

        world = dinfo.world_size
        self.lr = cfg.lr if cfg.lr is not None else 1e-4 * cfg.batch * world
        self.warmup = cfg.warmup if cfg.warmup is not None else min(2000, cfg.steps // 20)
        self.optimizer = make_optimizer(cfg.optimizer, self.policy.parameters(), self.lr, cfg.weight_decay)
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, _lr_lambda(self.warmup, cfg.steps, cfg.min_lr_ratio))
        if ckpt is not None:
            self.restore(ckpt)
            if self.changed:  # the restored optimiser holds the old rate and decay: run what config.json says
                self.scheduler.base_lrs = [self.lr for _ in self.scheduler.base_lrs]
                for group in self.optimizer.param_groups:
                    group.update(initial_lr=self.lr, weight_decay=cfg.weight_decay,
                                 lr=self.lr * self.scheduler.lr_lambdas[0](self.scheduler.last_epoch))
        self.train_policy: torch.nn.Module = self.policy
        if dinfo.enabled:
            from torch.nn.parallel import DistributedDataParallel

            self.train_policy = DistributedDataParallel(
                self.policy, device_ids=[device.index] if device.type == "cuda" else None)
        if dinfo.main:
            self._write_config()
            import yaml

            (self.run / "recipe.yaml").write_text(  # the run's options as a file: abm train --config RUN/recipe.yaml
                "# written by abm train: retrain with  abm train --config THIS_FILE --out NEW_RUN\n"
                + yaml.safe_dump(cfg.to_recipe(), sort_keys=False))
        sampler = StepSampler(len(self.dataset), cfg.batch, cfg.steps, self.start, world, dinfo.rank, cfg.seed)
        self.loader = torch.utils.data.DataLoader(
            self.dataset, batch_size=cfg.batch, sampler=sampler, num_workers=cfg.workers, collate_fn=collate,
            worker_init_fn=worker_init, pin_memory=device.type == "cuda",
        )
        return self

    def _write_config(self) -> None:
        """RUN/config.json: the run's options, language encoder, processes, learning rate and warm-up, what changed
        on resume, and why it stopped early (when it did)."""
        write_text_atomic(self.run / "config.json", json.dumps(
            {"train": self.trained.to_dict(), "language": self.language_spec, "world_size": self.dinfo.world_size,
             "lr": self.lr, "warmup": self.warmup, **({"changed_on_resume": self.changed} if self.changed else {}),
             **(self.stopped.to_dict() if self.stopped is not None else {})}, indent=2))

    def _resume_checkpoint(self) -> dict[str, Any] | None:
        if not self.cfg.resume:
            return None
        if not list_checkpoints(self.run):
            if self.dinfo.main:
                log.info("abm train: no checkpoint in %s; starting from scratch", self.run)
            return None
        ckpt = load_checkpoint(self.run)
        if int(ckpt["step"]) > self.cfg.steps:
            raise ConfigError(f"{self.run} is already at step {ckpt['step']}, past --steps {self.cfg.steps}: resume "
                              f"with --steps {ckpt['step']} or more")
        _check_same_data(self.run, ckpt.get("train_config") or {}, self.cfg)
        self.changed = changed_settings(ckpt.get("train_config") or {}, self.cfg)
        if self.changed:
            flags = {f.name: f.metadata.get("flag", "--" + f.name.replace("_", "-")) for f in fields(TrainConfig)}
            listed = ", ".join(f"{flags[k]} {old!r} -> {new!r}" for k, (old, new) in self.changed.items())
            if "optimizer" in self.changed:
                raise ConfigError(f"{self.run} was trained with --optimizer {self.changed['optimizer'][0]}; its "
                                  "optimiser state cannot continue under another optimizer: resume with the same one")
            if not self.cfg.accept_changed_config:
                raise ConfigError(f"{self.run} was trained with other settings ({listed}); resume with the same "
                                  "values, or pass --accept-changed-config to continue with the new ones")
            log.warning("abm train: continuing %s with changed settings: %s", self.run, listed)
        return ckpt

    def _dataset(self, source: EpisodeSource, augment: bool | None = None) -> KeyframeDataset:
        cfg, dinfo = self.cfg, self.dinfo
        augment = cfg.augment if augment is None else augment
        cache = Path(cfg.cache_dir) if cfg.cache_dir is not None else self.run / "cache"
        opts = self.policy.sample_options()
        if dinfo.main and ((opts["mask"] and GROUNDERS[self.grounder_config.kind].cached) or opts["features"]):
            # the explicit grounding step (what `abm data ground` does ahead of time); resumable
            made = ground_keyframes(source, self.policy.workspace, self.grounder_config, cache, mask=opts["mask"],
                                    features=opts["features"], augment=augment, camera_names=cfg.camera_names,
                                    show_progress=cfg.progress, destination=opts["destination"])
            log.info("abm train: grounded %d keyframes with %s into %s", made, self.grounder_config.kind, cache)
        if dinfo.enabled:
            dist.barrier()  # rank 0 has filled the grounding cache
        return KeyframeDataset(source, self.policy.workspace, self.grounder_config, **opts, augment=augment,
                               cache_dir=cache, seed=cfg.seed, camera_names=cfg.camera_names,
                               memory_mb=cfg.memory_mb)

    # ------------------------------------------------------------------ checkpoints
    def state(self, step: int) -> dict[str, Any]:
        """Checkpoint payload: the policy's plus the optimiser, scheduler, RNG and run bookkeeping."""
        return {
            **self.policy.checkpoint_payload(), "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(), "rng": _rng_state(), "step": step,
            "train_config": self.trained.to_dict(), "world_size": self.dinfo.world_size,
            "elapsed_s": self.elapsed_s(),  # training time over all resumes
            **(self.stopped.to_dict() if self.stopped is not None else {}),  # a finished run: not continued
        }

    def restore(self, ckpt: dict[str, Any]) -> None:
        """Load policy, optimiser, scheduler and RNG states and the step from a checkpoint."""
        self.policy.load_networks(ckpt)
        self.optimizer.load_state_dict(ckpt["optimizer"])
        use_fused_adamw(self.optimizer)
        self.scheduler.load_state_dict(ckpt["scheduler"])
        _set_rng_state(ckpt["rng"])
        self.start = int(ckpt["step"])
        self.prior_s = float(ckpt.get("elapsed_s", 0.0))
        self.stopped = FlatStop.from_record(ckpt)
        if self.dinfo.main:
            log.info("abm train: resumed from %s at step %d", ckpt["path"], self.start)

    def save(self, step: int) -> None:
        """Checkpoint at ``step`` (rank 0) and prune old ones."""
        if self.dinfo.main:
            save_checkpoint(checkpoint_path(self.run, step), self.state(step))
            prune_checkpoints(self.run, self.cfg.keep_checkpoints)

    def elapsed_s(self) -> float:
        return self.prior_s + time.perf_counter() - self._t0

    # ------------------------------------------------------------------ steps
    def step(self, batch: dict[str, Any]) -> dict[str, float]:
        """One optimiser step on a batch; returns the loss terms (averaged over ranks)."""
        loss, metrics = self.train_policy(batch)  # KeyframePolicy.compute_loss (through DDP when distributed)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.cfg.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        vals = torch.stack([metrics[k] for k in LOSS_TERMS]).float()
        if self.dinfo.enabled:
            # the SIGTERM flag rides along: any rank's request stops every rank after this same step (a rank that
            # stopped alone would leave the others waiting in the next all-reduce)
            vals = torch.cat([vals, vals.new_tensor([1.0 if self.term.flag else 0.0])])
            dist.all_reduce(vals)
            self.stop_requested = bool(vals[-1].item() > 0)
            vals = vals[:-1] / self.dinfo.world_size
        else:
            self.stop_requested = self.term.flag
        return dict(zip(LOSS_TERMS, vals.tolist(), strict=True))

    def validation_loss(self) -> float | None:
        """Mean total loss on the first :data:`VAL_SAMPLES` held-out keyframes (``--val-data``), or ``None``."""
        if self.val_dataset is None or len(self.val_dataset) == 0:
            return None
        indices = list(range(min(VAL_SAMPLES, len(self.val_dataset))))
        total, count = 0.0, 0
        self.policy.eval()
        try:
            with torch.no_grad():
                for i in range(0, len(indices), self.cfg.batch):
                    chunk = indices[i:i + self.cfg.batch]
                    loss, _ = self.policy(collate([self.val_dataset[j] for j in chunk]))
                    total += float(loss) * len(chunk)
                    count += len(chunk)
        finally:
            self.train_policy.train()
        return total / count

    def flat_stop(self, logger: _Logger, step: int) -> FlatStop | None:
        """Whether the run's curve is flat at the checkpoint ``step`` (:attr:`TrainConfig.flat_rule`, decided on rank
        0 from the logged rows and shared with every rank); ``None``: train on."""
        rule = self.cfg.flat_rule
        if rule is None:
            return None
        loss = "val_total" if self.val_dataset is not None else "total"
        found = [rule.check(logger.curve(loss), step, loss) if self.dinfo.main else None]
        if self.dinfo.enabled:
            dist.broadcast_object_list(found, src=0)
        return found[0]

    def startup_summary(self) -> str:
        """What is trained on what, where: the first lines of a training log."""
        cfg = self.cfg
        keyframes = len(self.dataset)
        val = (f"; validation: {len(self.val_dataset)} held-out keyframes from {cfg.val_data}"
               if self.val_dataset is not None else "")
        return (f"abm train: {cfg.method} ({self.policy_config.preset}, {self.policy.num_parameters():,} "
                f"parameters, {self.policy_config.resolution}² views) on {self.episodes_used} episodes / {keyframes} "
                f"keyframes{f' of {cfg.data}' if cfg.data else ''}{val}\n"
                f"abm train: {cfg.steps} steps of batch {cfg.batch} x {self.dinfo.world_size} process(es), "
                f"{cfg.optimizer} lr {self.lr:g}, warm-up {self.warmup}"
                f"{' (not shorter than the run: the lr never reaches its peak)' if self.warmup >= cfg.steps else ''}"
                f", device {self.device}, grounder "
                f"{self.grounder_config.kind}, from step {self.start}; run folder {self.run}")

    def fit(self, on_step: Callable[[int, dict[str, float]], None] | None = None) -> dict[str, Any]:
        """Train from the current step to ``cfg.steps``, or to the checkpoint where its curve is flat
        (``cfg.stop_when_flat``); returns the run summary (also ``summary.json``). A run that stopped early is
        finished: resumed, it trains no further and returns its summary."""
        cfg, dinfo = self.cfg, self.dinfo
        if self.stopped is not None:
            return self._finished_summary()
        world = dinfo.world_size
        logger = _Logger(self.run, self.start, dinfo.main)
        step, last = self.start, {}
        self._t0 = time.perf_counter()
        tick, tick_step = self._t0, step
        if dinfo.main:
            log.info(self.startup_summary())
        bar = Progress(cfg.steps, f"train {cfg.method}/{cfg.preset}", "steps", initial=step, bar=cfg.progress,
                       enabled=dinfo.main)
        with self.term:  # SIGTERM: finish the step, save, stop like Ctrl-C
            try:
                self.train_policy.train()
                for batch in self.loader:
                    last = self.step(batch)
                    step += 1
                    checkpoint = step % cfg.checkpoint_every == 0 or step == cfg.steps
                    val = self.validation_loss() if checkpoint and dinfo.main else None
                    if val is not None:
                        bar.postfix["val"] = round(val, 4)
                        bar.write(f"train {cfg.method}/{cfg.preset}: step {step}, loss {last['total']:.4f}, "
                                  f"validation loss {val:.4f}")
                    bar.update(1, loss=round(last["total"], 4))
                    flat_check = checkpoint and step != cfg.steps and cfg.flat_rule is not None
                    if step % cfg.log_every == 0 or step == cfg.steps or val is not None or flat_check:
                        now = time.perf_counter()
                        sps = (step - tick_step) * cfg.batch * world / max(now - tick, 1e-9)
                        tick, tick_step = now, step
                        lr = float(self.scheduler.get_last_lr()[0])
                        logger.log({"step": step, "lr": lr, **last, "samples_per_s": sps,
                                    "elapsed_s": self.elapsed_s(), "val_total": "" if val is None else val})
                    if on_step is not None:
                        on_step(step, last)
                    self.stopped = self.flat_stop(logger, step) if flat_check else None
                    if self.stopped is not None:  # the last checkpoint is written below, with the reason
                        if dinfo.main:
                            log.info(self.stopped.message())
                            self._write_config()
                        break
                    if step % cfg.checkpoint_every == 0 and step != cfg.steps:
                        self.save(step)
                    if self.stop_requested and step != cfg.steps:
                        raise KeyboardInterrupt
            except KeyboardInterrupt:
                self.save(step)
                if dinfo.main:
                    log.warning("abm train: interrupted; checkpoint saved at step %d (continue with --resume)", step)
                raise
            finally:
                bar.close()
                logger.close()
        if step > self.start or not list_checkpoints(self.run):
            self.save(step)
        return self._summary(step, last)

    def _summary(self, step: int, last: dict[str, float]) -> dict[str, Any]:
        dinfo = self.dinfo
        digest = parameter_digest(self.policy)  # both networks of a two-stage policy
        digests = [digest]
        if dinfo.enabled:
            gathered: list[Any] = [None] * dinfo.world_size
            dist.all_gather_object(gathered, digest)
            digests = list(gathered)
        summary = {
            "method": self.cfg.method, "preset": self.policy_config.preset, "steps": step, "final_loss": last,
            "parameters": self.policy.num_parameters(), "world_size": dinfo.world_size,
            "parameter_digests": digests, "ranks_in_sync": len(set(digests)) == 1,
            "seconds": time.perf_counter() - self._t0, "checkpoint": str(checkpoint_path(self.run, step)),
            **(self.stopped.to_dict() if self.stopped is not None else {}),
        }
        if dinfo.main:
            write_text_atomic(self.run / "summary.json", json.dumps(summary, indent=2))
        self._leave_process_group()
        return summary

    def _finished_summary(self) -> dict[str, Any]:
        """A run that stopped early, resumed: nothing is trained; its summary.json (written when it stopped, else
        written now)."""
        assert self.stopped is not None
        if self.dinfo.main:
            log.info("abm train: %s is finished: it stopped at step %d, its curve flat (summary.json); train "
                     "into a new --out folder to train it further", self.run, self.stopped.step)
        written = self.run / "summary.json"
        if not written.is_file():  # a carried checkpoint, restored into a fresh folder
            return self._summary(self.start, {})
        summary: dict[str, Any] = json.loads(written.read_text())
        self._leave_process_group()
        return summary

    def _leave_process_group(self) -> None:
        """Every rank leaves the process group together, with nothing else holding it.

        DistributedDataParallel keeps its own reference to the group (and its reducer sits in reference cycles), so
        ``destroy_process_group`` alone would leave the gloo/nccl backend alive until the garbage collector or the
        interpreter's exit frees it. Freed at exit, its C++ threads can abort the process after the run has finished
        ("terminate called without an active exception", seen once in CI under torchrun). The wrapper is dropped
        and collected here, so the backend is freed in the main thread while the interpreter is whole."""
        if self.dinfo.enabled:
            self.train_policy = self.policy
            gc.collect()
            dist.barrier()
            dist.destroy_process_group()
            gc.collect()


def train(
    cfg: TrainConfig,
    episodes: Sequence[Episode] | None = None,
    on_step: Callable[[int, dict[str, float]], None] | None = None,
) -> dict[str, Any]:
    """Train (or resume) a policy; returns the run summary (also written to ``out/summary.json``).

    Args:
        cfg: run options.
        episodes: in-memory episodes (instead of ``cfg.data``).
        on_step: called after every optimiser step with ``(step, losses)`` (rank-averaged losses).

    Raises:
        ValueError: bad options, a checkpoint of another variant/preset, or an empty selection;
            :class:`abm.files.FolderBusyError` when another process writes ``cfg.out``.
    """
    if int(os.environ.get("RANK", "0")) != 0:  # rank 0 holds the run folder's lock for every rank
        return Trainer(cfg, episodes).build().fit(on_step)
    with FolderLock(cfg.out, "abm train"):
        return Trainer(cfg, episodes).build().fit(on_step)
