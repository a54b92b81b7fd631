"""Behaviour-cloning training loop for every policy variant (single process or ``torchrun`` DDP).

* LAMB (``torch_optimizer.Lamb``), linear warm-up then cosine decay, gradient-norm clipping,
  bf16 autocast on CUDA.
* Data: :class:`~abm.data.keyframes.KeyframeDataset` with the deterministic
  :class:`~abm.data.keyframes.StepSampler` (rank-sharded like ``DistributedSampler``), so a run
  resumed from a checkpoint sees exactly the batches the uninterrupted run would have seen.
* Distributed: launched by ``torchrun`` (``WORLD_SIZE`` > 1) the loop joins a process group (gloo on
  CPU, nccl on CUDA) and wraps the model in ``DistributedDataParallel``; rank 0 logs and saves.
* :class:`Trainer` splits a run into build / step / save-restore / fit; :func:`train` runs one.
  Messages go through :mod:`logging` (logger ``abm.train.loop``; the ``abm`` command shows INFO).
* Outputs in the run folder: ``config.json``, ``log.csv``, ``tb/`` (TensorBoard),
  ``checkpoints/step_XXXXXXXX.pt`` (every ``checkpoint_every`` steps, at the end, and on Ctrl-C),
  ``summary.json``.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import math
import os
import random
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist

from abm.data.keyframes import (
    EpisodeSource,
    KeyframeDataset,
    StepSampler,
    check_inside_workspace,
    collate,
    ground_keyframes,
    worker_init,
)
from abm.files import FolderLock, write_text_atomic
from abm.grounding.conditioning import make_grounder_from_spec
from abm.policy.checkpoint import (
    checkpoint_path,
    list_checkpoints,
    load_checkpoint,
    prune_checkpoints,
    save_checkpoint,
)
from abm.policy.config import PolicyConfig, check_compatible
from abm.policy.keyframe_policy import LOSS_TERMS, KeyframePolicy
from abm.policy.language import make_language_encoder
from abm.train.config import TrainConfig
from abm.types import Episode

log = logging.getLogger(__name__)

LOG_FIELDS = ("step", "lr", "total", "translation", "rotation", "gripper", "collision", "samples_per_s",
              "elapsed_s")


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
    """``lamb`` (``torch_optimizer.Lamb``, the paper's) or ``adamw``."""
    if name == "lamb":
        from torch_optimizer import Lamb

        return Lamb(params, lr=lr, weight_decay=weight_decay)
    if name == "adamw":
        return torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    raise ValueError(f"unknown optimizer {name!r}; choose 'lamb' or 'adamw'")


def _lr_lambda(warmup: int, total: int, min_ratio: float) -> Callable[[int], float]:
    def f(step: int) -> float:
        if warmup > 0 and step < warmup:
            return (step + 1) / warmup
        progress = min(max(step - warmup, 0) / max(total - warmup, 1), 1.0)
        return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return f


def _rng_state() -> dict[str, Any]:
    state = {
        "torch": torch.get_rng_state(),
        # as (name, tensor, pos, has_gauss, cached) so checkpoints load with weights_only=True
        "numpy": _numpy_state_plain(np.random.get_state()),  # noqa: NPY002
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _numpy_state_plain(state: tuple) -> tuple:
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


def build_policy_config(cfg: TrainConfig, lang_dim: int, ifd_dim: int | None) -> PolicyConfig:
    """The run's :class:`PolicyConfig`: preset + variant, language width from the encoder, overrides."""
    overrides = dict(cfg.policy_overrides)
    overrides.setdefault("lang_dim", lang_dim)
    if ifd_dim is not None:
        overrides.setdefault("ifd_feature_dim", ifd_dim)
    return PolicyConfig.from_preset(cfg.preset, cfg.method, **overrides)


def language_spec(cfg: TrainConfig, lang_dim: int) -> dict[str, Any]:
    kind = cfg.language or ("clip" if cfg.grounder == "clip" else "hash")
    if kind == "hash":
        return {"kind": "hash", "dim": lang_dim, "tokens": 77, "seed": 0}
    if kind == "clip":
        return {"kind": "clip", **cfg.grounder_options}
    raise ValueError(f"unknown language encoder {kind!r}; use 'hash' or 'clip'")


def _episode_source(cfg: TrainConfig, episodes: Sequence[Episode] | None) -> EpisodeSource:
    if episodes is not None:
        return EpisodeSource(list(episodes))
    if cfg.data is None:
        raise ValueError("no training data: give --data DIR (an episode store) or --synthetic N")
    from abm.data.episode_store import EpisodeStore, check_episodes  # owned by the data package

    store = EpisodeStore(cfg.data)
    indices = store.select(tasks=cfg.tasks, splits=cfg.splits)
    if not indices:
        raise ValueError(f"no episodes in {cfg.data} for tasks {cfg.tasks} and splits {cfg.splits}")
    store.check_consistent(indices)
    if cfg.verify:
        bad = check_episodes([store.episodes[i].path for i in indices], cfg.data)
        if bad:
            shown = "; ".join(reason for _, reason in bad[:3]) + (f"; and {len(bad) - 3} more" if len(bad) > 3 else "")
            raise ValueError(f"{len(bad)} episode file(s) in {cfg.data} fail verification: {shown}. Run abm data "
                             "generate again with the same arguments (it re-creates them), or pass --no-verify "
                             "to train on them anyway")
    return EpisodeSource(store, indices)


class _Logger:
    """CSV + TensorBoard logging on rank 0; truncates rows past the resume step."""

    def __init__(self, run: Path, start_step: int, enabled: bool) -> None:
        self.enabled = enabled
        self.tb = None
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
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(run / "tb"), purge_step=start_step + 1 if start_step else None)
        except ImportError:  # tensorboard is optional
            self.tb = None

    def log(self, row: dict[str, float]) -> None:
        if not self.enabled:
            return
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, LOG_FIELDS).writerow({k: row.get(k, "") for k in LOG_FIELDS})
        if self.tb is not None:
            step = int(row["step"])
            for k in ("total", "translation", "rotation", "gripper", "collision"):
                self.tb.add_scalar(f"loss/{k}", row[k], step)
            self.tb.add_scalar("lr", row["lr"], step)
            self.tb.add_scalar("samples_per_s", row["samples_per_s"], step)

    def close(self) -> None:
        if self.tb is not None:
            self.tb.close()


_RUN_FILES = ("config.json", "log.csv", "summary.json")

# Options that shape the optimisation: ``--resume`` keeps them unless told otherwise (``--steps`` may grow; the
# model's own options are checked by ``check_compatible``; the rest - paths, devices, logging - may change).
RESUME_FIXED = ("tasks", "splits", "batch", "lr", "optimizer", "warmup", "min_lr_ratio", "weight_decay", "grad_clip",
                "grounder", "grounder_options", "language", "seed", "augment", "camera_names")


def changed_settings(saved: dict[str, Any], cfg: TrainConfig) -> dict[str, tuple[Any, Any]]:
    """``{option: (value in the checkpoint, value now)}`` of the :data:`RESUME_FIXED` options that differ."""
    now = cfg.to_dict()
    return {k: (saved[k], now[k]) for k in RESUME_FIXED if k in saved and saved[k] != now[k]}


def _claim_run_folder(run: Path, cfg: TrainConfig, dinfo: DistInfo) -> None:
    """Refuse to train into a folder that holds another run, unless resuming or told to overwrite."""
    existing = list_checkpoints(run)
    occupied = bool(existing) or any((run / name).exists() for name in _RUN_FILES)
    if occupied and not cfg.resume:
        if not cfg.overwrite:
            at = f" (checkpoint at step {existing[-1][0]})" if existing else ""
            raise ValueError(f"{run} already holds a training run{at}: continue it with --resume, train into a "
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

    # ------------------------------------------------------------------ build
    def build(self) -> Trainer:
        """Set everything up; raises ``ValueError`` on bad options before anything is written."""
        cfg = self.cfg
        self.dinfo = dinfo = _setup_distributed(cfg.device)
        self.device = device = torch.device(cfg.device)
        if device.type == "cuda":
            if not torch.cuda.is_available():
                raise ValueError("--device cuda requested but CUDA is not available")
            if dinfo.enabled:
                self.device = device = torch.device("cuda", dinfo.local_rank)
            torch.cuda.set_device(device)
        if cfg.resume and cfg.overwrite:
            raise ValueError("--resume and --overwrite contradict each other: choose one")
        ckpt = self._resume_checkpoint()

        torch.manual_seed(cfg.seed)
        np.random.seed(cfg.seed)  # noqa: NPY002 - global RNG of third-party code
        random.seed(cfg.seed)
        base_lang = int(cfg.policy_overrides.get("lang_dim", 512))
        self.language_spec = ckpt["language"] if ckpt is not None else language_spec(cfg, base_lang)
        encoder = make_language_encoder(self.language_spec)
        self.grounder_spec = gspec = ({"kind": "oracle"} if cfg.grounder == "oracle"
                                      else {"kind": cfg.grounder, **cfg.grounder_options})
        ifd_dim = None
        if cfg.method == "ifd":
            if cfg.grounder != "clip":
                raise ValueError("method 'ifd' re-renders CLIP features: use --grounder clip")
            g = make_grounder_from_spec(gspec)
            ifd_dim = getattr(g, "feature_dim", None) or getattr(getattr(g, "backbone", None), "embed_dim", None)
        self.policy_config = build_policy_config(cfg, encoder.dim, ifd_dim)
        if ckpt is not None:
            check_compatible(PolicyConfig.from_dict(ckpt["policy_config"]), self.policy_config)
        self.policy = KeyframePolicy(self.policy_config, encoder, gspec, cfg.camera_names).to(device)
        source = _episode_source(cfg, self.episodes)
        check_inside_workspace(source, self.policy.workspace)  # every rank, before anything is written
        _claim_run_folder(self.run, cfg, dinfo)  # options are valid: now the folder may be written
        self.dataset = self._dataset(source)

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
            write_text_atomic(self.run / "config.json", json.dumps(
                {"train": cfg.to_dict(), "policy": self.policy_config.to_dict(), "language": self.language_spec,
                 "grounder": gspec, "world_size": world, "lr": self.lr, "warmup": self.warmup,
                 **({"changed_on_resume": self.changed} if self.changed else {})}, indent=2))
        sampler = StepSampler(len(self.dataset), cfg.batch, cfg.steps, self.start, world, dinfo.rank, cfg.seed)
        self.loader = torch.utils.data.DataLoader(
            self.dataset, batch_size=cfg.batch, sampler=sampler, num_workers=cfg.workers, collate_fn=collate,
            worker_init_fn=worker_init, pin_memory=device.type == "cuda",
        )
        return self

    def _resume_checkpoint(self) -> dict[str, Any] | None:
        if not self.cfg.resume:
            return None
        if not list_checkpoints(self.run):
            if self.dinfo.main:
                log.info("abm train: no checkpoint in %s; starting from scratch", self.run)
            return None
        ckpt = load_checkpoint(self.run)
        if int(ckpt["step"]) > self.cfg.steps:
            raise ValueError(f"{self.run} is already at step {ckpt['step']}, past --steps {self.cfg.steps}: resume "
                             f"with --steps {ckpt['step']} or more")
        self.changed = changed_settings(ckpt.get("train_config") or {}, self.cfg)
        if self.changed:
            flags = {f.name: f.metadata.get("flag", "--" + f.name.replace("_", "-")) for f in fields(TrainConfig)}
            listed = ", ".join(f"{flags[k]} {old!r} -> {new!r}" for k, (old, new) in self.changed.items())
            if "optimizer" in self.changed:
                raise ValueError(f"{self.run} was trained with --optimizer {self.changed['optimizer'][0]}; its "
                                 "optimiser state cannot continue under another optimizer: resume with the same one")
            if not self.cfg.accept_changed_config:
                raise ValueError(f"{self.run} was trained with other settings ({listed}); resume with the same "
                                 "values, or pass --accept-changed-config to continue with the new ones")
            log.warning("abm train: continuing %s with changed settings: %s", self.run, listed)
        return ckpt

    def _dataset(self, source: EpisodeSource) -> KeyframeDataset:
        cfg, dinfo = self.cfg, self.dinfo
        cache = Path(cfg.cache_dir) if cfg.cache_dir is not None else self.run / "cache"
        opts = self.policy.sample_options()
        if dinfo.main and ((opts["mask"] and self.grounder_spec["kind"] != "oracle") or opts["features"]):
            # the explicit grounding step (what `abm data ground` does ahead of time); resumable
            made = ground_keyframes(source, self.policy.workspace, self.grounder_spec, cache, mask=opts["mask"],
                                    features=opts["features"], augment=cfg.augment, camera_names=cfg.camera_names,
                                    show_progress=cfg.progress)
            log.info("abm train: grounded %d keyframes with %s into %s", made, self.grounder_spec["kind"], cache)
        if dinfo.enabled:
            dist.barrier()  # rank 0 has filled the grounding cache
        return KeyframeDataset(source, self.policy.workspace, self.grounder_spec, **opts, augment=cfg.augment,
                               cache_dir=cache, seed=cfg.seed, camera_names=cfg.camera_names)

    # ------------------------------------------------------------------ checkpoints
    def state(self, step: int) -> dict[str, Any]:
        """Checkpoint payload: the policy's plus the optimiser, scheduler, RNG and run bookkeeping."""
        return {
            **self.policy.checkpoint_payload(), "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(), "rng": _rng_state(), "step": step,
            "train_config": self.cfg.to_dict(), "world_size": self.dinfo.world_size,
            "elapsed_s": self.elapsed_s(),  # training time over all resumes
        }

    def restore(self, ckpt: dict[str, Any]) -> None:
        """Load policy, optimiser, scheduler and RNG states and the step from a checkpoint."""
        self.policy.model.load_state_dict(ckpt["model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.scheduler.load_state_dict(ckpt["scheduler"])
        _set_rng_state(ckpt["rng"])
        self.start = int(ckpt["step"])
        self.prior_s = float(ckpt.get("elapsed_s", 0.0))
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
            dist.all_reduce(vals)
            vals /= self.dinfo.world_size
        return dict(zip(LOSS_TERMS, vals.tolist(), strict=True))

    def fit(self, on_step: Callable[[int, dict[str, float]], None] | None = None) -> dict[str, Any]:
        """Train from the current step to ``cfg.steps``; returns the run summary (also ``summary.json``)."""
        from tqdm import tqdm

        cfg, dinfo = self.cfg, self.dinfo
        world = dinfo.world_size
        logger = _Logger(self.run, self.start, dinfo.main)
        step, last = self.start, {}
        self._t0 = time.perf_counter()
        tick, tick_step = self._t0, step
        bar = tqdm(total=cfg.steps, initial=step, desc=f"train {cfg.method}/{cfg.preset}",
                   disable=not (dinfo.main and cfg.progress), dynamic_ncols=True)
        try:
            self.train_policy.train()
            for batch in self.loader:
                last = self.step(batch)
                step += 1
                bar.update(1)
                bar.set_postfix(loss=f"{last['total']:.3f}")
                if step % cfg.log_every == 0 or step == cfg.steps:
                    now = time.perf_counter()
                    sps = (step - tick_step) * cfg.batch * world / max(now - tick, 1e-9)
                    tick, tick_step = now, step
                    logger.log({"step": step, "lr": self.scheduler.get_last_lr()[0], **last, "samples_per_s": sps,
                                "elapsed_s": self.elapsed_s()})
                if on_step is not None:
                    on_step(step, last)
                if step % cfg.checkpoint_every == 0 and step != cfg.steps:
                    self.save(step)
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
        digest = parameter_digest(self.policy.model)
        digests = [digest]
        if dinfo.enabled:
            gathered: list[Any] = [None] * dinfo.world_size
            dist.all_gather_object(gathered, digest)
            digests = list(gathered)
        summary = {
            "method": self.cfg.method, "preset": self.policy_config.preset, "steps": step, "final_loss": last,
            "parameters": self.policy.model.num_parameters(), "world_size": dinfo.world_size,
            "parameter_digests": digests, "ranks_in_sync": len(set(digests)) == 1,
            "seconds": time.perf_counter() - self._t0, "checkpoint": str(checkpoint_path(self.run, step)),
        }
        if dinfo.main:
            write_text_atomic(self.run / "summary.json", json.dumps(summary, indent=2))
        if dinfo.enabled:
            dist.barrier()
            dist.destroy_process_group()
        return summary


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
