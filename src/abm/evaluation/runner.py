"""Seeded policy rollouts in ABM-Bench and the success tables they produce.

Every (task, split, repeat, episode) uses the scene seed :func:`~abm.evaluation.results.eval_seed`, so
all methods face exactly the same scenes, and an outcome depends on nothing but the checkpoint, the scene and
the settings: not on the command, the worker it ran in or the backend (:mod:`abm.evaluation.policies`). Each
finished rollout is appended to ``OUT/outcomes.jsonl`` at once; re-running the same command skips what is there
(resume), and a rollout that raises is recorded as a failure with its error instead of stopping the evaluation.
"""

from __future__ import annotations

import json
import math
import re
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any, TypeVar, cast

from abm.errors import ConfigError, OutputError
from abm.evaluation import expert_cache
from abm.evaluation.expert_move import ExpertMove
from abm.evaluation.html_report import write_html_report
from abm.evaluation.plots import run_loss_curves, success_chart
from abm.evaluation.policies import (
    check_policies,
    code_digest,
    forget_policies,
    load_policy,
    needs_segmentation,
    rollout_state,
)
from abm.evaluation.results import (
    OUTCOME_ARCHIVE,
    EpisodeOutcome,
    OutcomeLog,
    RolloutKey,
    SuccessRate,
    aggregate,
    eval_seed,
    markdown_table,
    rollout_key,
    subgoal_rates,
    subgoal_results,
    trajectory_digest,
    write_csv,
    write_json,
    write_outcome_archive,
)
from abm.evaluation.scene_cache import forget_scenes, kept_scene
from abm.evaluation.settings import EvalSettings
from abm.evaluation.step_records import episode_failure, expert_keyframes, step_record
from abm.files import write_text_atomic
from abm.geometry import project_to_camera
from abm.grounding.decision import GroundingRecorder
from abm.grounding.visualize import hstack, label, overlay_views, upscale, vstack
from abm.language.roles import split_roles
from abm.policy.checkpoint import load_checkpoint, resolve_checkpoint
from abm.progress import Progress
from abm.ray_pool import RayActorPool
from abm.sim.cameras import single_threaded_rasterizer
from abm.workers import die_with_parent

_T = TypeVar("_T")


@dataclass(frozen=True)
class EvalJob:
    """One rollout to run: which policy on which seeded scene."""

    run: str
    method: str
    task: str
    split: str
    repeat: int
    episode: int
    seed: int
    gif_path: str = ""
    checkpoint: str = ""
    settings: str = ""

    @property
    def key(self) -> RolloutKey:
        """The key of this job's :class:`EpisodeOutcome` (:func:`rollout_key`)."""
        return rollout_key(self)


def _load_policy(run: str, settings: EvalSettings) -> Any:
    """A fresh copy of the policy for one rollout (:func:`abm.evaluation.policies.load_policy`)."""
    return load_policy(run, settings)


def run_job(job: EvalJob, settings: EvalSettings) -> EpisodeOutcome:
    """Roll out one episode; never raises (a crash becomes a failed outcome with its error text).

    The outcome depends on the job's checkpoint, task, split and seed and on ``settings`` only: the rollout gets
    a fresh copy of the policy, one torch thread and RNGs seeded from the scene seed
    (:func:`abm.evaluation.policies.rollout_state`), in whichever process it runs, and the scene as built fresh
    (the process keeps the last scene's compiled model and renderer for the next rollout on it, another model's:
    :mod:`abm.evaluation.scene_cache`); with a GIF it acts through
    ``explain()``, whose action is :meth:`act`'s. The process's GL rasterizer runs in the drawing thread
    (:func:`abm.sim.cameras.single_threaded_rasterizer`, unless the user set ``LP_NUM_THREADS``).
    """
    from abm.sim.env import run_policy  # mujoco (optional `sim` extra)

    single_threaded_rasterizer()  # before the process's first GL context

    start = time.perf_counter()
    steps = 0
    instruction = target = ""
    step_grounding: list[dict[str, Any] | None] = []  # per step, None without a mask
    replaced: list[Any] = []  # per step under --expert-keyframes: the prediction an expert keyframe replaced, or None
    try:
        expert_move = _expert_move(job, settings)  # before the rollout's RNGs are seeded: they stay untouched
        with rollout_state(job.seed):
            policy = _load_policy(job.checkpoint or job.run, settings)
            with kept_scene(job.task, job.split, job.seed, settings.resolution, settings.max_steps,
                            settings.splits_path, needs_segmentation(policy)) as env:
                instruction, target = env.instruction, ", ".join(env.target_names)
                policy.reset()
                explained: list[Any] = []
                # the decision abm run takes on each step's grounding, logged (evaluation acts anyway)
                recorder = GroundingRecorder(policy.grounder if policy.sample_options()["mask"] else None)

                def act(obs: Any) -> Any:
                    if not job.gif_path:
                        action = policy.act(obs, env.instruction, env.object_names)
                    else:
                        explained.append(policy.explain(obs, env.instruction, env.object_names))
                        action = explained[-1].action
                    if expert_move is not None:
                        executed = expert_move.choose(action, _holds(env))
                        replaced.append(action if executed is not action else None)
                        action = executed
                    decision = recorder.record()
                    step_grounding.append(None if decision is None else
                                          {k: decision[k] for k in ("found", "confidence", "target", "reason")})
                    return action

                with recorder:
                    episode = run_policy(env, act)
                expert = _expert_of(job, settings, env)  # after the rollout: the scene reset, the expert run
        steps = len(episode.steps)
        meta = episode.metadata
        held = bool(meta.get("held_target"))
        predicted = replaced or [None] * steps
        records = [step_record(action, motion, held_after, stop, expert, decided, own)
                   for (_, action), motion, held_after, stop, decided, own in zip(
                       episode.steps, meta["motions"], meta["held"], meta["stop_errors"], step_grounding, predicted,
                       strict=True)]
        failure = episode_failure(bool(episode.success), "", records)
        if job.gif_path:
            save_rollout_gif(episode, job.gif_path, result="success" if episode.success else failure)
            save_views_figure(explained, views_path(job.gif_path))
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed,
                              bool(episode.success), steps, time.perf_counter() - start,
                              checkpoint=job.checkpoint, settings=job.settings, failure=failure,
                              subgoals=subgoal_results(_roles(episode), held, bool(episode.success)),
                              instruction=instruction, target=target,
                              trajectory=trajectory_digest(a for _, a in episode.steps), code=code_digest(),
                              grounding=[g for g in step_grounding if g is not None],
                              step_records=[r.to_json() for r in records])
    except Exception as err:  # noqa: BLE001 - an episode crash must not abort the evaluation
        text = " ".join(f"{type(err).__name__}: {err}".split())
        # the frame's file by name only: no folder of this machine in a log an experiment commits
        frames = traceback.format_exc(limit=3).strip().splitlines()
        tb = [re.sub(r'File "[^"]*[/\\]', 'File "', line) for line in frames]
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed, False,
                              steps, time.perf_counter() - start, error=f"{text} | {tb[-3] if len(tb) > 2 else ''}",
                              checkpoint=job.checkpoint, settings=job.settings, failure="crashed",
                              instruction=instruction, target=target, code=code_digest())


_EXPERTS: dict[tuple[str, str, int, str | None], tuple[Any, ...]] = {}
"""Expert keyframes per scene (task, split, seed, split file), kept for the process: every method of an
evaluation faces the same scenes."""


def _expert_path(job: EvalJob, settings: EvalSettings) -> Path | None:
    """The disk cache's file of the job's scene (:mod:`abm.evaluation.expert_cache`), ``None`` with the cache off."""
    folder = expert_cache.cache_folder()
    if folder is None:
        return None
    return expert_cache.scene_file(folder, job.task, job.split, job.seed, settings.splits_path, code_digest())


def _known_expert(job: EvalJob, settings: EvalSettings) -> tuple[Any, ...] | None:
    """The expert's keyframes of the job's scene if this process or the disk cache has them, else ``None``."""
    key = (job.task, job.split, job.seed, settings.splits_path)
    if key not in _EXPERTS:
        path = _expert_path(job, settings)
        keyframes = None if path is None else expert_cache.read(path)
        if keyframes is None:
            return None
        _remember(key, keyframes)
    return _EXPERTS[key]


def _remember(key: tuple[str, str, int, str | None], keyframes: tuple[Any, ...]) -> None:
    """Keep a scene's expert keyframes for the process (at most 512 scenes: the oldest is forgotten)."""
    _EXPERTS[key] = keyframes
    if len(_EXPERTS) > 512:
        del _EXPERTS[next(iter(_EXPERTS))]


def _expert_of(job: EvalJob, settings: EvalSettings, env: Any) -> tuple[Any, ...]:
    """The expert's keyframes on the job's scene: known already (:func:`_known_expert`), or
    :func:`abm.evaluation.step_records.expert_keyframes` run in ``env`` once its rollout is over and kept in the
    process and on disk; ``()`` when the expert cannot run there (the step records then name no expert keyframe;
    the outcome is unchanged)."""
    known = _known_expert(job, settings)
    if known is not None:
        return known
    try:
        keyframes = expert_keyframes(env)
    except Exception:  # noqa: BLE001 - the expert is extra data: it must never fail the episode
        return ()
    path = _expert_path(job, settings)
    if path is not None:
        expert_cache.write(path, keyframes)
    _remember((job.task, job.split, job.seed, settings.splits_path), keyframes)
    return keyframes


def _expert_move(job: EvalJob, settings: EvalSettings) -> ExpertMove | None:
    """The expert-move rule of a rollout under ``--expert-keyframes`` (``None`` without), with the expert's
    keyframes of the job's scene known already or computed in a separate copy of it (:func:`_expert_of`), so the
    rollout's own scene and RNGs are untouched."""
    if settings.expert_keyframes is None:
        return None
    known = _known_expert(job, settings)
    if known is not None:
        return ExpertMove(known)
    from abm.sim.env import make_env  # mujoco (optional `sim` extra)

    with make_env(job.task, job.split, job.seed, settings.resolution, max_steps=settings.max_steps,
                  splits_path=settings.splits_path) as scene:
        return ExpertMove(_expert_of(job, settings, scene))


def _holds(env: Any) -> bool:
    """Whether the gripper holds the task's held object now (as :func:`abm.sim.env.run_policy` records it)."""
    carried = env.task.held_object(env.instance)
    return carried is not None and carried in env.sim.held_objects()


def _worker_init() -> None:
    die_with_parent()  # before the slow torch import, so there is no window to outlive the command
    import torch

    torch.set_num_threads(1)


def method_labels(runs: Sequence[str | Path]) -> dict[str, str]:
    """Table labels of runs: the policy variant, or ``variant (path)`` when several checkpoint files share a
    variant, with as many trailing parts of each run's path as tell them apart (``abm (seed1/abm)``). Runs that
    are the same checkpoint file get the same label; different files never do."""
    variants = {str(r): load_checkpoint(r, map_location="cpu")["policy_config"]["variant"] for r in runs}
    files = {str(r): checkpoint_of(r) for r in runs}
    labels: dict[str, str] = {}
    for variant in dict.fromkeys(variants.values()):
        group = [r for r in variants if variants[r] == variant]
        shown = {files[r]: Path(r).resolve() for r in reversed(group)}  # per file: the first run naming it
        if len(shown) == 1:
            labels.update({r: variant for r in group})
            continue
        depth = 1
        while len({_tail(p, depth) for p in shown.values()}) < len(shown) and depth < 64:
            depth += 1
        labels.update({r: f"{variant} ({_tail(shown[files[r]], depth)})" for r in group})
    return labels


def _tail(path: Path, depth: int) -> str:
    return "/".join(path.parts[-depth:])


def same_file_runs(runs: Sequence[str | Path]) -> list[str]:
    """``runs`` without repeats of a checkpoint file (the first run naming each file is kept)."""
    seen: dict[str, str] = {}
    for r in map(str, runs):
        seen.setdefault(checkpoint_of(r), r)
    return list(seen.values())


def check_labels(runs: Sequence[str], labels: dict[str, str]) -> None:
    """Refuse (``ValueError``) labels that would pool two different checkpoint files into one table row."""
    owner: dict[str, str] = {}
    for r in runs:
        label, file = labels[r], checkpoint_of(r)
        if owner.setdefault(label, file) != file:
            raise ConfigError(f"the runs {owner[label]} and {file} have the same table label {label!r}, so their "
                              "episodes would be pooled into one row: give each run its own label")


def plan_jobs(
    runs: Sequence[str | Path],
    tasks: Sequence[str],
    split: str,
    episodes: int,
    repeats: int,
    out_dir: Path,
    gifs: int = 0,
    labels: dict[str, str] | None = None,
) -> list[EvalJob]:
    """All rollouts of the protocol, in a fixed order; GIFs for the first ``gifs`` episodes of repeat 0."""
    labels = labels or method_labels(runs)
    jobs = []
    for run in map(str, runs):
        for task in tasks:
            for repeat in range(repeats):
                for ep in range(episodes):
                    gif = ""
                    if repeat == 0 and ep < gifs:
                        gif = str(out_dir / "gifs" / f"{labels[run]}_{task}_{split}_{ep:03d}.gif".replace(" ", "_"))
                    jobs.append(EvalJob(run, labels[run], task, split, repeat, ep, eval_seed(repeat, ep), gif))
    return jobs


def evaluate(
    runs: Sequence[str | Path],
    tasks: Sequence[str],
    split: str,
    out_dir: str | Path,
    episodes: int = 25,
    repeats: int = 5,
    workers: int = 1,
    settings: EvalSettings | None = None,
    gifs: int = 0,
    progress: bool = True,
    labels: dict[str, str] | None = None,
    runner: Callable[[EvalJob, EvalSettings], EpisodeOutcome] = run_job,
    backend: str = "local",
    ray_address: str | None = None,
    collect: list[EpisodeOutcome] | None = None,
) -> list[SuccessRate]:
    """Evaluate policies on one split and write ``outcomes.jsonl``, ``results.{json,csv,md}`` and the outcomes the
    tables count, with their per-step records, compressed (``outcomes.jsonl.xz``,
    :func:`~abm.evaluation.results.write_outcome_archive`) to ``out_dir``.

    Args:
        runs: training run folders (or checkpoint files), one per method.
        tasks: task names.
        split: ``seen``, ``unseen`` or ``compositional``.
        episodes, repeats: the protocol (paper: 25 episodes x 5 repeats).
        workers: parallel rollout processes (each loads its own policy and simulator).
        gifs: front-camera GIFs with the predicted keyframes for this many episodes per task.
        labels: run -> method label for the tables (default: from the checkpoints, see :func:`method_labels`).
        runner: the function that rolls out one job (replaceable for tests).
        backend: ``"local"`` (in-process for one worker, else a process pool) or ``"ray"`` (``workers`` Ray
            actors at ``ray_address``, or a local Ray; :mod:`abm.ray_pool`). The outcomes are the same on
            every backend and for any ``workers`` (see :func:`run_job`).
        collect: if given, receives the outcomes the returned rates are computed from (crashed ones have an
            ``error``; each is from this call, as crashed episodes are always rolled out again).

    Runs naming the same checkpoint file are evaluated once. Before the first rollout, the default runner loads
    every run's policy once in this process (:func:`abm.evaluation.policies.check_policies`): a run that cannot
    load raises :class:`abm.evaluation.policies.PolicyLoadError` and nothing is rolled out.

    Returns:
        success rates of every (method, task) on ``split``, from the outcomes of exactly the planned
        rollouts (same checkpoints, same settings); older lines of the log are kept but not reported.
    """
    cell = EvalCell(runs, tasks, split, Path(out_dir), episodes, repeats, settings or EvalSettings(), gifs, labels)
    return evaluate_together([cell], workers, progress, runner, backend, ray_address,
                             [collect] if collect is not None else None)[0]


@dataclass(frozen=True)
class EvalCell:
    """One results folder of :func:`evaluate_together`: runs on the tasks of one split, with its protocol and
    settings (:func:`evaluate`'s arguments of the same names)."""

    runs: Sequence[str | Path]
    tasks: Sequence[str]
    split: str
    out_dir: Path
    episodes: int = 25
    repeats: int = 5
    settings: EvalSettings = EvalSettings()
    gifs: int = 0
    labels: dict[str, str] | None = None


@dataclass
class _Planned:
    """A cell's outcome log, its whole plan and the rollouts of the plan its log does not hold yet."""

    cell: EvalCell
    log: OutcomeLog
    plan: list[EvalJob]
    jobs: list[EvalJob]


def _plan_cell(cell: EvalCell) -> _Planned:
    runs = same_file_runs(cell.runs)
    labels = cell.labels or method_labels(runs)
    check_labels(runs, labels)
    log = OutcomeLog(cell.out_dir / "outcomes.jsonl")
    done = log.done()
    checkpoints = {str(r): checkpoint_of(r) for r in runs}
    plan = [replace(j, checkpoint=checkpoints[j.run], settings=cell.settings.signature())
            for j in plan_jobs(runs, cell.tasks, cell.split, cell.episodes, cell.repeats, cell.out_dir, cell.gifs,
                               labels)]
    check_same_evaluation(log.read(), plan, cell.out_dir, record=False)
    return _Planned(cell, log, plan, [j for j in plan if j.key not in done])


def evaluate_together(
    cells: Sequence[EvalCell],
    workers: int = 1,
    progress: bool = True,
    runner: Callable[[EvalJob, EvalSettings], EpisodeOutcome] = run_job,
    backend: str = "local",
    ray_address: str | None = None,
    collect: Sequence[list[EpisodeOutcome]] | None = None,
) -> list[list[SuccessRate]]:
    """:func:`evaluate` of several results folders at once (e.g. each model of a split in its own folder, as the
    experiment engine keeps them): every folder's rollouts of a scene go to one process one after another, so the
    scene is built once for all of them (:mod:`abm.evaluation.scene_cache`); each outcome goes to its own folder's
    log and each folder gets its tables as :func:`evaluate` writes them. ``collect``: one list per cell. Returns
    each cell's success rates, in the cells' order. The outcomes are those of evaluating each cell alone."""
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}; choose local or ray")
    planned = [_plan_cell(cell) for cell in cells]
    in_process = workers <= 1 and backend == "local"
    if runner is run_job and any(p.jobs for p in planned):  # fail before any rollout (and any file) on a bad policy
        for p in planned:
            if p.jobs:
                check_policies(list(dict.fromkeys(j.checkpoint or j.run for j in p.jobs)), p.cell.settings)
        if not in_process:
            forget_policies()  # the workers load their own
    for p in planned:
        p.cell.out_dir.mkdir(parents=True, exist_ok=True)
        check_same_evaluation(p.log.read(), p.plan, p.cell.out_dir)
    pending = [(i, job) for i, p in enumerate(planned) for job in p.jobs]
    splits = ", ".join(dict.fromkeys(cell.split for cell in cells))
    bar = Progress(len(pending), f"eval {splits}", "episodes", bar=progress)
    successes = 0

    def record(group: Sequence[tuple[int, EvalJob]], outcomes: Sequence[EpisodeOutcome]) -> None:
        nonlocal successes
        for (i, _), outcome in zip(group, outcomes, strict=True):
            planned[i].log.append(outcome)
            successes += outcome.success
            bar.update(1, success=f"{successes}/{bar.n + 1}")

    # every model's (every cell's) rollout of a scene in one process, one after another
    groups = scene_groups(pending, job_of=lambda item: item[1])
    if in_process:
        try:
            for group in groups:
                record(group, run_group(runner, [(job, planned[i].cell.settings) for i, job in group]))
        finally:
            forget_scenes()
    else:
        with _pool(backend, workers, ray_address) as pool:
            futures = {pool.submit(run_group, runner, [(job, planned[i].cell.settings) for i, job in group]): group
                       for group in groups}
            for fut in as_completed(futures):
                record(futures[fut], fut.result())
    bar.close()
    rates = []
    for i, p in enumerate(planned):
        wanted = {j.key for j in p.plan}
        latest = {o.key: o for o in p.log.read() if o.key in wanted}  # the log may hold older checkpoints too
        if collect is not None:
            collect[i].extend(latest.values())
        run_loss_curves({j.method: j.run for j in p.plan}, p.cell.out_dir / "training.png")
        write_outcome_archive(latest.values(), p.cell.out_dir / OUTCOME_ARCHIVE)  # what the tables count
        rates.append(write_reports(list(latest.values()), p.cell.out_dir))
    return rates


def scene_groups(items: Sequence[_T], job_of: Callable[[_T], EvalJob] | None = None) -> list[list[_T]]:
    """``items`` (jobs, or what ``job_of`` reads a job from) grouped by their job's scene (task, split, seed), the
    groups in the order of each scene's first item and a group's items in their given order: a process rolling out
    a group builds its scene once (:mod:`abm.evaluation.scene_cache`), not once per model. The outcomes do not
    depend on the order."""
    groups: dict[tuple[str, str, int], list[_T]] = {}
    for item in items:
        job = job_of(item) if job_of is not None else cast(EvalJob, item)
        groups.setdefault((job.task, job.split, job.seed), []).append(item)
    return list(groups.values())


def run_group(runner: Callable[[EvalJob, EvalSettings], EpisodeOutcome],
              jobs: Sequence[tuple[EvalJob, EvalSettings]]) -> list[EpisodeOutcome]:
    """``runner`` on each (job, settings) of one scene group (:func:`scene_groups`), in order, in this process."""
    return [runner(job, settings) for job, settings in jobs]


def crash_summary(outcomes: Sequence[EpisodeOutcome]) -> str:
    """One line on the crashed rollouts among ``outcomes`` (``""`` if none): how many, the first one (protocol
    order) with its checkpoint, episode and error, and the fix."""
    crashed = sorted((o for o in outcomes if o.error), key=lambda o: (o.split, o.task, o.repeat, o.episode, o.method))
    if not crashed:
        return ""
    first = crashed[0]
    every = ", every episode (the table measures nothing)" if len(crashed) == len(outcomes) else ""
    return (f"{len(crashed)} of {len(outcomes)} episode(s) crashed and count as failures{every}; first error: "
            f"{first.checkpoint or first.method}, {first.task} ({first.split}) episode {first.episode} (seed "
            f"{first.seed}): {' '.join(first.error.split())}; fix the cause and run the same command again (crashed "
            "episodes are rolled out again, finished ones are kept)")


PROTOCOL_FILE = "evaluation.json"


def check_same_evaluation(existing: Sequence[EpisodeOutcome], plan: Sequence[EvalJob], out: Path,
                          record: bool = True) -> None:
    """Refuse (``ValueError``) to add rollouts to a folder whose outcomes were made with other evaluation
    settings or on other tasks / splits, so a table never mixes two protocols and an accidental call does not
    append to a finished evaluation; then (``record``) note this protocol in ``out/evaluation.json``. More episodes,
    repeats or runs, and newer checkpoints, are allowed (and resume works as before).

    Folders written before ``evaluation.json`` existed are checked against their outcomes instead: other
    settings, or tasks this call does not plan, are refused.
    """
    wanted = {"tasks": sorted({f"{j.task} ({j.split})" for j in plan}), "settings": sorted({j.settings for j in plan})}
    path = out / PROTOCOL_FILE
    if path.is_file():
        had = json.loads(path.read_text())
    else:
        recorded = [o for o in existing if o.settings]  # logs written before settings were recorded: unknown
        had = {"tasks": sorted({f"{o.task} ({o.split})" for o in recorded} | set(wanted["tasks"])),
               "settings": sorted({o.settings for o in recorded} | set(wanted["settings"]))}
    problems = [f"{key} {', '.join(had[key])} there vs {', '.join(wanted[key])} now"
                for key in ("tasks", "settings") if had.get(key) != wanted[key]]
    if problems:
        raise OutputError(f"{out} holds the outcomes of another evaluation ({'; '.join(problems)}): evaluate into "
                          f"a new --out folder, or delete {out / 'outcomes.jsonl'} and {path.name} to start over")
    if record:
        path.write_text(json.dumps(wanted, indent=2) + "\n")


def _pool(backend: str, workers: int, ray_address: str | None) -> Any:
    if backend == "ray":
        return RayActorPool(workers, address=ray_address)
    return ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_worker_init)


def checkpoint_of(run: str | Path) -> str:
    """The checkpoint file a run folder (or checkpoint path) resolves to; ``str(run)`` if none exists."""
    try:
        return str(resolve_checkpoint(run).resolve())
    except (FileNotFoundError, ValueError):
        return str(run)


def write_reports(outcomes: Sequence[EpisodeOutcome], out_dir: Path) -> list[SuccessRate]:
    """Aggregate outcomes into ``out_dir``/results.json, results.csv, results.md, success.png (bar chart) and
    report.html (the per-episode view: failure reasons and rollout GIFs from ``out_dir``/gifs)."""
    rates = aggregate(outcomes)
    write_tables(rates, out_dir)
    if rates:
        success_chart(rates, out_dir / "success.png")
    write_html_report(outcomes, out_dir / "report.html", out_dir / "gifs")
    with (out_dir / "results.md").open("a") as f:
        if rates:
            f.write("\n![success rate per task, split and method; error bars: std over repeats](success.png)\n")
        if (out_dir / "training.png").is_file():
            f.write("\n![training losses of the evaluated runs](training.png)\n")
        sub = subgoal_rates(outcomes)
        if sub:
            f.write("\nSuccess per sub-goal (%), two-target instructions (1: X grasped, 2: X placed in Y):\n\n"
                    "| method | task | split | sub-goal 1 | sub-goal 2 | episodes |\n|---|---|---|---|---|---|\n")
            for method, task, split, rates_, n in sub:
                f.write(f"| {method} | {task} | {split} | " + " | ".join(f"{r:.1f}" for r in rates_[:2])
                        + f" | {n} |\n")
        f.write("\nPer-episode report (failure reasons, rollout GIFs): [report.html](report.html)\n")
    return rates


def write_tables(rates: Sequence[SuccessRate], out_dir: Path) -> None:
    """Write success rates as ``out_dir``/results.json, results.csv and results.md."""
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(rates, out_dir / "results.json")
    write_csv(rates, out_dir / "results.csv")
    write_text_atomic(out_dir / "results.md", markdown_table(rates, splits=["seen", "unseen", "compositional"]) + "\n")


def save_rollout_gif(episode: Any, path: str | Path, camera: str = "front", seconds_per_frame: float = 0.6,
                     result: str = "") -> None:
    """Write a GIF of one camera over the rollout, each frame marked with the keyframe predicted from it and
    captioned with the instruction, the step (``step 2/5``) and, on the last frame, ``result``."""
    from PIL import Image, ImageDraw

    frames = []
    for k, (obs, action) in enumerate(episode.steps):
        frame = obs.camera(camera)
        img = Image.fromarray(frame.rgb).resize((frame.width * 2, frame.height * 2), Image.Resampling.NEAREST)
        u, v, z = project_to_camera(action.position[None], frame.intrinsics, frame.extrinsics)[0]
        if z > 0 and math.isfinite(u) and math.isfinite(v):
            draw = ImageDraw.Draw(img)
            cx, cy = 2 * u + 1, 2 * v + 1
            color = (0, 255, 0) if action.gripper_open else (255, 0, 255)
            draw.ellipse([cx - 5, cy - 5, cx + 5, cy + 5], outline=color, width=2)
        last = k == len(episode.steps) - 1
        frames.append(_caption(img, episode.instruction, f"step {k + 1}/{len(episode.steps)}",
                               result if last else ""))
    if frames:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(seconds_per_frame * 1000),
                       loop=0)


def _caption(img: Any, instruction: str, step: str, result: str) -> Any:
    """``img`` (PIL) above a black strip: the instruction (wrapped to the width), the step and the result
    (one line each, the same height on every frame so the GIF's frames match)."""
    import textwrap

    from PIL import Image, ImageDraw

    chars = max(8, img.width // 6)  # PIL's default font is ~6 px per character
    lines = [*(textwrap.wrap(instruction, chars) or [""]), step, result]
    out = Image.new("RGB", (img.width, img.height + 12 * len(lines) + 4), (0, 0, 0))
    out.paste(img, (0, 0))
    draw = ImageDraw.Draw(out)
    for i, line in enumerate(lines):
        draw.text((3, img.height + 2 + 12 * i), line if len(line) <= chars else line[:chars - 3] + "...",
                  fill=(255, 255, 255))
    return out


def _roles(episode: Any) -> int:
    """How many sub-goals the episode's instruction has (1 when it cannot be split)."""
    try:
        return len(split_roles(episode.instruction, episode.object_names)[0])
    except ValueError:
        return 1


def views_path(gif_path: str | Path) -> Path:
    """Where the heatmap overlays of the rollout whose GIF is ``gif_path`` go (``X.gif`` -> ``X_views.png``)."""
    p = Path(gif_path)
    return p.with_name(p.stem + "_views.png")


def save_views_figure(explanations: Sequence[Any], path: str | Path, max_side: int = 96) -> Path | None:
    """One row per rollout step: the policy's five virtual views with the target tinted cyan, the mask
    channel's centre ring and the predicted translation heatmap (:func:`abm.grounding.visualize.overlay_views`).

    ``explanations`` are :class:`abm.policy.PolicyExplanation` s; views are enlarged to about ``max_side`` px.
    """
    from PIL import Image

    rows = []
    for k, seen in enumerate(explanations):
        views = overlay_views(seen.view_rgb, seen.view_target, seen.heatmaps, seen.view_mask)
        factor = max(1, max_side // views[0].shape[0])
        row = hstack([label(upscale(v, factor), name) for v, name in zip(views, seen.view_names, strict=True)])
        rows.append(label(row, f"step {k}: {'open' if seen.action.gripper_open else 'close'}"))
    if not rows:
        return None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(vstack(rows)).save(path)
    return path
