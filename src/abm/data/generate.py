"""Generate expert demonstrations on ABM-Bench into an episode directory (parallel, resumable).

Layout: ``OUT/<task>/<split>/episode_<seed>.h5``. Seeds ``seed, seed+1, ...`` are tried in order until
``episodes`` successful demonstrations exist; a seed whose expert failed leaves a small
``episode_<seed>.failed`` marker so that re-running skips it, and finished episodes are never redone.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abm.configuration import CAMERA_RESOLUTION
from abm.data.episode_store import check_episodes, find_episode_files, load_metadata, read_info, save_episode
from abm.errors import ConfigError
from abm.progress import Progress
from abm.ray_pool import RayActorPool
from abm.registry import UnknownNameError
from abm.sim.tasks import TASKS, get_task
from abm.workers import die_with_parent

if TYPE_CHECKING:
    from abm.ray_pool import RayActorPool

MAX_SEED_FACTOR = 3  # give up after trying this many seeds per requested episode
ALL_TASKS = "all"


class EvaluationOnlyTaskError(ConfigError):
    """Demonstrations were requested for an evaluation-only (compositional) task."""


def trainable_tasks() -> list[str]:
    """Names of the tasks demonstrations can be generated for (not the evaluation-only ones), sorted."""
    return sorted(name for name, cls in TASKS.items() if not cls.evaluation_only)


def expand_tasks(spec: str) -> list[str]:
    """``"all"`` -> every trainable task; ``"a,b"`` -> ``["a", "b"]``. Raises ``KeyError`` for unknown
    names (:class:`~abm.registry.UnknownNameError`) and :class:`EvaluationOnlyTaskError` for evaluation-only tasks."""
    if spec.strip() == ALL_TASKS:
        return trainable_tasks()
    names = [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in TASKS]
    if unknown or not names:
        raise UnknownNameError(f"unknown task(s) {unknown or [spec]}; known tasks: {', '.join(sorted(TASKS))} "
                               f"(or '{ALL_TASKS}')")
    for name in names:
        check_trainable(name)
    return names


def check_trainable(task: str) -> None:
    """Raise :class:`EvaluationOnlyTaskError` if ``task`` is evaluation-only."""
    if TASKS[task].evaluation_only:
        raise EvaluationOnlyTaskError(
            f"task {task!r} is evaluation-only (compositional: a trained skill on another task's objects); "
            f"no demonstrations are generated for it. Trainable tasks: {', '.join(trainable_tasks())}")


@dataclass
class GenerationReport:
    """What a generation run did.

    Attributes:
        created: episodes written by this run.
        skipped: successful episodes already present (resume).
        failed_seeds: seeds whose expert failed in this run.
        seconds: wall-clock time of this run.
    """

    created: int
    skipped: int
    failed_seeds: list[int]
    seconds: float

    @property
    def episodes_per_minute(self) -> float:
        return 60.0 * self.created / self.seconds if self.seconds > 0 else 0.0


def episode_path(out: Path, task: str, split: str, seed: int) -> Path:
    return Path(out) / task / split / f"episode_{seed:06d}.h5"


def _failed_marker(path: Path) -> Path:
    return path.with_suffix(".failed")


def generate_one(task: str, split: str, seed: int, out: str, resolution: int,
                 splits_path: str | None, dense_fps: float | None = None) -> tuple[int, bool, str]:
    """Run the expert for one seed and save it if successful. Returns ``(seed, success, note)``."""
    from abm.sim.env import make_env, run_expert  # mujoco (optional `sim` extra)

    path = episode_path(Path(out), task, split, seed)
    with make_env(task, split, seed, resolution=resolution, splits_path=splits_path) as env:
        episode = run_expert(env, record=True, dense_fps=dense_fps)
    if episode.success:
        save_episode(episode, path)
        return seed, True, ""
    marker = _failed_marker(path)
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text(f"expert failed; motions: {episode.metadata.get('motions')}\n")
    return seed, False, str(episode.metadata.get("motions"))


def generate_remote(task: str, split: str, seed: int, out: str, resolution: int, splits_path: str | None,
                    dense_fps: float | None = None) -> tuple[int, bool, str, bytes]:
    """:func:`generate_one` on a machine that may not see ``out`` (a Ray node): the episode is written to a
    local temporary folder and returned as the file's bytes, for the driver to store."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="abm-gen-") as tmp:
        sd, ok, note = generate_one(task, split, seed, tmp, resolution, splits_path, dense_fps)
        path = episode_path(Path(tmp), task, split, seed)
        return sd, ok, note, path.read_bytes() if ok else b""


def _store_remote(out: Path, task: str, split: str, result: tuple[int, bool, str, bytes]) -> tuple[int, bool, str]:
    """Write what :func:`generate_remote` returned where :func:`generate_one` would have (atomically)."""
    import os

    sd, ok, note, payload = result
    path = episode_path(out, task, split, sd)
    path.parent.mkdir(parents=True, exist_ok=True)
    if ok:
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        tmp.write_bytes(payload)
        os.replace(tmp, path)
    else:
        _failed_marker(path).write_text(f"expert failed; motions: {note}\n")
    return sd, ok, note


def _remove_corrupt_episodes(out: Path, folder: Path) -> set[int]:
    """Delete the episodes of ``folder`` that fail verification (so they are generated again, never counted);
    returns the seeds that have an episode file or a failure marker."""
    import logging
    import re

    if not folder.is_dir():
        return set()
    for path, reason in check_episodes(find_episode_files(folder), out):
        logging.getLogger("abm").warning("%s fails verification (%s); generating it again", path.name, reason)
        path.unlink(missing_ok=True)
    found = (re.fullmatch(r"episode_(\d+)\.(h5|failed)", p.name) for p in folder.iterdir())
    return {int(m.group(1)) for m in found if m}


def _check_resume_settings(folder: Path, resolution: int, dense_fps: float | None = None) -> None:
    """Refuse to add episodes of another camera resolution (or dense rate) to a folder (they could not be
    trained or exported together)."""
    existing = find_episode_files(folder) if folder.is_dir() else []
    if not existing:
        return
    signature = read_info(existing[0]).cameras
    size = signature.rsplit("@", 1)[-1]
    if size != f"{resolution}x{resolution}":
        raise ConfigError(f"{folder} holds episodes recorded at {size} pixels ({existing[0].name}); this run asks for "
                          f"--resolution {resolution}. Use the same resolution to resume, or a new --out folder.")
    stored = load_metadata(existing[0]).get("dense_fps")
    if (float(stored) if stored else None) != (float(dense_fps) if dense_fps else None):
        have = f"dense at {stored} fps" if stored else "keyframes only"
        want = f"--dense at {dense_fps} fps" if dense_fps else "keyframes only (no --dense)"
        raise ConfigError(f"{folder} holds episodes recorded {have} ({existing[0].name}); this run asks for {want}. "
                          "Use the same setting to resume, or a new --out folder.")


def generate(task: str, split: str, episodes: int, out: str | Path, workers: int = 1, seed: int = 0,
             resolution: int = CAMERA_RESOLUTION, splits_path: str | Path | None = None, progress: bool = True,
             dense_fps: float | None = None, backend: str = "local", ray_address: str | None = None
             ) -> GenerationReport:
    """Make sure ``episodes`` successful demonstrations of ``task``/``split`` exist under ``out``.

    ``dense_fps`` also records the full trajectory at that control rate; ``backend`` ``"ray"`` runs the
    workers as Ray actors (:mod:`abm.ray_pool`) on the cluster at ``ray_address`` (or a local Ray)."""
    from abm.sim.env import make_env  # mujoco (optional `sim` extra): `abm data` commands run without it

    get_task(task)  # unknown task -> KeyError
    check_trainable(task)
    make_env(task, split, seed, resolution=resolution, splits_path=splits_path)  # validates early
    out = Path(out)
    start = time.perf_counter()
    done = 0
    pending_seeds: list[int] = []
    s = seed
    limit = seed + MAX_SEED_FACTOR * max(episodes, 1) + 10
    on_disk = _remove_corrupt_episodes(out, out / task / split)
    _check_resume_settings(out / task / split, resolution, dense_fps)
    # Resume: count what exists, queue the gaps. Past the last seed on disk nothing exists, so the scan stops
    # there and the pool draws the following seeds one by one (any --episodes count costs no memory up front).
    scan_end = min(limit, max(on_disk, default=seed - 1) + 1)
    while done + len(pending_seeds) < episodes and s < scan_end:
        path = episode_path(out, task, split, s)
        if path.is_file():
            done += 1
        elif not _failed_marker(path).is_file():
            pending_seeds.append(s)
        s += 1
    skipped = done
    failed: list[int] = []
    created = 0
    bar = Progress(episodes, f"generate {task}/{split}", "episodes", initial=done, bar=progress)
    ctx = multiprocessing.get_context("spawn")
    next_seed = s
    args = (str(out), int(resolution), str(splits_path) if splits_path else None, dense_fps)
    with _pool(backend, workers, ctx, ray_address) as pool:
        running: set[Future[Any]] = set()  # generate_one's or generate_remote's result, by backend
        worker: Callable[..., tuple[int, bool, str] | tuple[int, bool, str, bytes]] = (
            generate_remote if backend == "ray" else generate_one)
        queue = list(pending_seeds)

        def submit_more() -> None:
            nonlocal next_seed
            while len(running) < max(1, workers) and done + created + len(running) < episodes:
                if queue:
                    sd = queue.pop(0)
                elif next_seed < limit:
                    sd = next_seed
                    next_seed += 1
                    path = episode_path(out, task, split, sd)
                    if path.is_file() or _failed_marker(path).is_file():
                        continue
                else:
                    return
                running.add(pool.submit(worker, task, split, sd, *args))

        submit_more()
        while running:
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in finished:
                running.discard(fut)
                sd, ok, note = _store_remote(out, task, split, fut.result()) if backend == "ray" else fut.result()
                if ok:
                    created += 1
                    bar.update(1)
                else:
                    failed.append(sd)
                    bar.write(f"seed {sd}: expert failed ({note}); trying another seed")
            submit_more()
    bar.close()
    return GenerationReport(created, skipped, sorted(failed), time.perf_counter() - start)


def _pool(backend: str, workers: int, ctx: BaseContext, ray_address: str | None
          ) -> ProcessPoolExecutor | RayActorPool:
    """The executor of the generation workers: the local process pool or Ray actors."""
    if backend == "ray":
        return RayActorPool(max(1, workers), address=ray_address)
    if backend != "local":
        raise ValueError(f"unknown backend {backend!r}; choose local or ray")
    return ProcessPoolExecutor(max_workers=max(1, workers), mp_context=ctx, initializer=die_with_parent)
