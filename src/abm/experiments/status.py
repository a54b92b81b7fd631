"""What ``abm experiment status`` says beside each job's state: a finished job's minutes where no job log of this
working folder has them, the edition's time per stage (:func:`stage_time_lines`), what the report's README gate
waits for (:func:`readme_gate_lines`), what is kept and carried (files and sizes), and an estimate of what is left.

Minutes of a finished job (:func:`kept_minutes`), when OUT/jobs.jsonl has none (a fresh clone): a training's
``train_minutes`` from the zoo index or ``KEPT/runs.json``, an evaluation's episodes' seconds summed (the
rollouts' own time, over every worker).

The estimate (:func:`estimate`) multiplies what is left by a measured rate and names where the rate comes from:
training steps left (the budget less the step the run's log or carried checkpoint reached) × seconds per step of
this spec's runs (their logs' ``elapsed_s`` in OUT or the carry, else its finished runs' minutes in the zoo index or
``KEPT/runs.json``, else the minutes of the zoo's models of an earlier edition trained with the same network sizes:
:func:`network_of`); evaluation episodes left × seconds per episode of this spec's evaluated episodes (OUT, the
carry, the kept archives), else of ``docs/results/rollout_speed.json`` (``benchmarks/rollout_speed.py``);
diagnosis jobs left × the mean minutes of the finished diagnosis jobs of the same kind in this working folder
(:func:`diagnosis_rates`).
"""

from __future__ import annotations

import csv
import json
import re
import socket
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from statistics import mean
from typing import Any, Protocol

from abm.evaluation.results import OUTCOME_ARCHIVE, OutcomeLog, read_outcome_archive
from abm.experiments.report import Context, Outcomes, collect_cells, status_line
from abm.experiments.spec import STAGES, ExperimentSpec
from abm.experiments.state import (
    DESTINATION_GROUNDING_JOB,
    Layout,
    job_events,
    last_logged_step,
    pid_alive,
    span_minutes,
    stage_spans,
)

ROLLOUT_SPEED = "docs/results/rollout_speed.json"  #: seconds per rollout measured by benchmarks/rollout_speed.py
_STEP_FILE = re.compile(r"^step_(\d+)\.pt$")


class StatusJob(Protocol):
    """What the status reads of a job (:class:`abm.experiments.stages.Job` is one)."""

    id: str
    stage: str
    state: str
    minutes: float | None


@dataclass(frozen=True)
class Rate:
    """A measured rate: ``seconds`` per unit, and where it was measured (``source``, as the status says it)."""

    seconds: float
    source: str


# ------------------------------------------------------------------------------------------------ files
def folder_files(folder: Path) -> list[tuple[Path, int]]:
    """``(file, bytes)`` of every file under ``folder``, by path (``[]`` when it does not exist)."""
    return sorted((p, p.stat().st_size) for p in folder.rglob("*") if p.is_file()) if folder.is_dir() else []


def megabytes(size: int) -> str:
    """A file size as the status shows it (``24.3 MB``, ``33 kB``)."""
    return f"{size / 1e6:.1f} MB" if size >= 1e6 else f"{size / 1e3:.0f} kB"


def carried_lines(layout: Layout) -> list[str]:
    """The carry as the status shows it: every carried file with its size, and the total."""
    if layout.carry is None:
        return ["carried: nothing (this experiment keeps no carry)"]
    files = folder_files(layout.carry)
    shown = layout.show(layout.carry)
    if not files:
        return [f"carried: nothing in {shown}"]
    return [f"carried in {shown} ({len(files)} files, {megabytes(sum(s for _, s in files))}):",
            *(f"  {path.relative_to(layout.carry).as_posix()}  {megabytes(size)}" for path, size in files)]


def kept_line(layout: Layout, sources: Iterable[str] = ()) -> str:
    """What is kept: the committed folder KEPT (files, size) and the further records the report reads
    (``sources``, root-relative files)."""
    files = folder_files(layout.kept)
    parts = [f"{layout.show(layout.kept)}/ ({len(files)} files, {megabytes(sum(s for _, s in files))})"
             if files else f"nothing yet in {layout.show(layout.kept)}/"]
    parts += [f"{source} ({megabytes((layout.root / source).stat().st_size)})" for source in dict.fromkeys(sources)
              if (layout.root / source).is_file()]
    return "kept: " + ", ".join(parts)


# ---------------------------------------------------------------------------------------------- minutes
def _finished_runs(spec: ExperimentSpec, layout: Layout) -> dict[str, dict[str, Any]]:
    """Run -> its summary with ``train_minutes`` and ``steps``: the zoo index's entry, else ``KEPT/runs.json``'s."""
    found: dict[str, dict[str, Any]] = {}
    for path in (layout.kept / "runs.json", *([layout.zoo / "index.json"] if layout.zoo is not None else [])):
        if path.is_file():
            for entry in json.loads(path.read_text()):
                run = next((r for r in spec.runs if spec.zoo_name(r) == entry.get("name") or r == entry.get("name")
                            and path.parent == layout.kept), None)
                if run is not None and entry.get("train_minutes") is not None and entry.get("steps"):
                    found[run] = entry
    return found


def episode_seconds(layout: Layout, name: str, split: str) -> list[float]:
    """The seconds of every episode evaluated of ``name`` on ``split``: OUT's outcomes, else the carried ones, else
    the kept archive (``[]``: none)."""
    eval_dir = layout.eval_dir(name, split)
    for log in (eval_dir / "outcomes.jsonl", *([layout.carry / "eval" / name / split / "outcomes.jsonl"]
                                               if layout.carry is not None else [])):
        if log.is_file():
            return [o.seconds for o in OutcomeLog(log).read()]
    archive = layout.kept / f"{name}_{split}_{OUTCOME_ARCHIVE}"
    return [o.seconds for o in read_outcome_archive(archive)] if archive.is_file() else []


def kept_minutes(spec: ExperimentSpec, layout: Layout, job: StatusJob) -> float | None:
    """A finished job's minutes from what is kept (see the module docstring), ``None`` when nothing says."""
    parts = job.id.split("/")
    if job.stage == "train":
        entry = _finished_runs(spec, layout).get(parts[1])
        return float(entry["train_minutes"]) if entry else None
    if job.stage == "eval" and len(parts) == 3:
        seconds = episode_seconds(layout, parts[1], parts[2])
        return sum(seconds) / 60 if seconds else None
    return None


# ------------------------------------------------------------------------------------------- stage times
def stage_time_lines(layout: Layout, jobs: Sequence[StatusJob]) -> list[str]:
    """The edition's time per stage: the wall time (the stage times of OUT and KEPT, every session added up,
    :func:`abm.experiments.state.stage_minutes`, where the report's setup states OUT's only; a stage running now in a
    live engine on this host counted up to now) and the jobs' own minutes added up per stage (each job's minutes as
    the status shows them: this working folder's job log, else what is kept; a job not done yet adds the spans its
    sessions logged; trainings side by side each add theirs)."""
    wall, started = stage_spans(layout.times, layout.kept / layout.times.name)
    running = set()
    for (stage, session), start in started.items():
        host, _, pid = session.rpartition(":")
        if host == socket.gethostname() and pid.isdigit() and pid_alive(int(pid)):
            wall[stage] = wall.get(stage, 0.0) + (time.time() - start) / 60
            running.add(stage)
    order = [*STAGES, *sorted(set(wall) - set(STAGES))]
    shown = [f"{stage} {wall[stage]:.0f}{' (running)' if stage in running else ''}" for stage in order
             if stage in wall]
    lines = [f"wall time per stage, every session added up (min): {', '.join(shown)}; {sum(wall.values()):.0f} in "
             "all" if shown else "wall time per stage: no stage has run yet"]
    timed: dict[str, list[float]] = {}
    events = job_events(layout)
    for job in jobs:  # a done or running job's minutes, else what its unfinished sessions logged
        minutes = job.minutes if job.minutes is not None else span_minutes(events.get(job.id, []))
        if minutes is not None:
            timed.setdefault(job.stage, []).append(minutes)
    if timed:
        lines.append("job time per stage, each job's own minutes added up (min): " + ", ".join(
            f"{stage} {sum(timed[stage]):.0f} ({len(timed[stage])} job{'s' if len(timed[stage]) > 1 else ''})"
            for stage in STAGES if stage in timed))
    return lines


# ------------------------------------------------------------------------------------------- README gate
def readme_gate_lines(spec: ExperimentSpec, layout: Layout) -> list[str]:
    """Whether the report's README gate (``report.readme_when``) is open, and if not what it waits for, from the
    cells evaluated here or kept (:func:`abm.experiments.report.gate.status_line`; ``[]`` without a gate)."""
    if spec.report.readme_when is None:
        return []
    return status_line(Context(spec, Outcomes(cells=collect_cells(spec, layout, kept=True)), layout))


# --------------------------------------------------------------------------------------------- estimate
def _logged_rate(log: Path) -> tuple[int, float] | None:
    """``(step, elapsed seconds)`` of a training log's last row (``None``: no row with a time)."""
    if not log.is_file():
        return None
    with log.open() as f:
        rows = list(csv.DictReader(f))
    if not rows or not rows[-1].get("elapsed_s") or not int(rows[-1]["step"]):
        return None
    return int(rows[-1]["step"]), float(rows[-1]["elapsed_s"])


def step_rate(spec: ExperimentSpec, layout: Layout) -> Rate | None:
    """Seconds per training step of this spec's runs: their logs (OUT, else the carry), else its finished runs'
    minutes; ``None`` when none is measured."""
    logged = []
    for run in spec.runs:
        for log in (layout.run_dir(run) / "log.csv", *([layout.carry / run / "log.csv"] if layout.carry else [])):
            if (found := _logged_rate(log)) is not None:
                logged.append((run, found[1] / found[0]))
                break
    if logged:
        return Rate(mean(s for _, s in logged), "the training logs of " + ", ".join(run for run, _ in logged))
    finished = _finished_runs(spec, layout)
    if finished:
        return Rate(mean(60 * float(e["train_minutes"]) / int(e["steps"]) for e in finished.values()),
                    "the minutes of the finished runs " + ", ".join(finished))
    alike = _same_network_models(spec, layout)
    if alike:
        return Rate(mean(60 * float(e["train_minutes"]) / int(e["steps"]) for e in alike),
                    "the zoo's models with this spec's network sizes: " + ", ".join(e["name"] for e in alike))
    return None


NETWORK_KEYS = ("batch", "resolution", "patch_size", "rotation_crop", "zoom_size", "zoom_resolution",
                "zoom_patch_size")
"""The recipe entries of the zoo index (:func:`abm.experiments.report.runs.describe_run`) that set a training step's
cost; an entry it leaves out is off (0) in that recipe."""


def network_of(recipe: dict[str, Any]) -> tuple[Any, ...]:
    """A recipe's network sizes (:data:`NETWORK_KEYS`, an absent key as 0): what a step's cost depends on."""
    return tuple(recipe.get(key) or 0 for key in NETWORK_KEYS)


def _same_network_models(spec: ExperimentSpec, layout: Layout) -> list[dict[str, Any]]:
    """The zoo index's trained models (with ``train_minutes`` and ``steps``) whose network sizes are those of one
    of this spec's runs: an earlier edition's rate for a spec none of whose runs has trained yet."""
    index = layout.zoo / "index.json" if layout.zoo is not None else None
    if index is None or not index.is_file():
        return []
    wanted = set()
    for run in spec.runs.values():
        policy = run.config.policy
        keys = NETWORK_KEYS[1:] if policy.zoom_size else [k for k in NETWORK_KEYS[1:] if not k.startswith("zoom")]
        wanted.add(network_of({"batch": run.config.batch, **{key: getattr(policy, key) for key in keys}}))
    return [e for e in json.loads(index.read_text()) if isinstance(e.get("recipe"), dict)
            and e.get("train_minutes") is not None and e.get("steps") and network_of(e["recipe"]) in wanted]


def episode_rate(spec: ExperimentSpec, layout: Layout) -> Rate | None:
    """Seconds per evaluation episode: this spec's evaluated episodes, else the repository's rollout-speed
    measurement (the ``total`` rows of the commit measured last); ``None`` when neither exists."""
    seconds = [s for name in [*spec.runs, *(v.name for v in spec.evaluation.variants)]
               for split in spec.evaluation.splits for s in episode_seconds(layout, name, split.split)]
    if seconds:
        return Rate(mean(seconds), f"{len(seconds)} episodes evaluated by this spec")
    speed = layout.root / ROLLOUT_SPEED
    # the totals of rollouts with the checkpoints' own grounders (a NAME@GROUNDER row is another protocol's)
    rows = [r for r in json.loads(speed.read_text()) if r.get("stage") == "total" and "@" not in r.get("model", "")
            ] if speed.is_file() else []
    if not rows:
        return None
    newest = rows[-1].get("commit")  # the file grows at its end: the latest code's rollouts, not its baselines'
    rows = [r for r in rows if r.get("commit") == newest]
    at = f" at {newest}" if newest else ""
    return Rate(mean(r["seconds_per_rollout"] for r in rows), f"{ROLLOUT_SPEED} ({len(rows)} measurements{at})")


def steps_done(layout: Layout, run: str) -> int:
    """The step a training reached: its log in OUT, else its carried checkpoint's (0: not started)."""
    logged = last_logged_step(layout.run_dir(run))
    if logged is not None:
        return logged
    carried = layout.carry / run if layout.carry is not None else None
    steps = [int(m.group(1)) for p in carried.glob("step_*.pt") if (m := _STEP_FILE.match(p.name))] \
        if carried is not None and carried.is_dir() else []
    return max(steps, default=0)


def episodes_left(spec: ExperimentSpec, layout: Layout, name: str, split: str) -> int:
    """Episodes an evaluation of ``name`` on ``split`` has yet to run (the protocol less those evaluated)."""
    tasks = spec.split_tasks().get(split, ())
    total = len(tasks) * spec.evaluation.episodes * spec.evaluation.repeats
    return max(0, total - len(episode_seconds(layout, name, split)))


def diagnosis_kind(job_id: str) -> str:
    """What a diagnosis job measures, so that a finished one's minutes stand for the others of its kind:
    ``skill-text probe`` (``diagnose/skill_text/RUN/TASK``), ``destination grounding`` (the spec's one grounder
    job) or ``keyframe accuracy`` (``diagnose/RUN``, ``diagnose/RUN@oracle``)."""
    if job_id.startswith("diagnose/skill_text/"):
        return "skill-text probe"
    return "destination grounding" if job_id == DESTINATION_GROUNDING_JOB else "keyframe accuracy"


def diagnosis_rates(jobs: Sequence[StatusJob]) -> dict[str, Rate]:
    """Kind (:func:`diagnosis_kind`) -> the mean seconds of this working folder's finished diagnosis jobs of that
    kind (their job log's minutes; a fresh clone has none, so nothing is estimated from it)."""
    done: dict[str, list[float]] = {}
    for job in jobs:
        if job.stage == "diagnose" and job.state == "done" and job.minutes is not None:
            done.setdefault(diagnosis_kind(job.id), []).append(job.minutes * 60)
    return {kind: Rate(mean(seconds), f"{len(seconds)} finished {kind} job(s) of this spec")
            for kind, seconds in done.items()}


def _minutes(value: float) -> str:
    return f"{value:.0f} min" if value >= 10 else f"{value:.1f} min"


def _cost(what: str, jobs: int, left: int, unit: str, rate: Rate | None, parallel: int, how: str
          ) -> tuple[str, float]:
    """One line of the estimate and its CPU minutes (0 without a rate): ``left`` units over ``jobs`` jobs at
    ``rate``, ``parallel`` at a time (``how``: what runs in parallel)."""
    head = f"  {what}: {jobs} job(s), {left} {unit}s left"
    if rate is None:
        return head + ": no speed measured yet", 0.0
    minutes = left * rate.seconds / 60
    return (f"{head} × {rate.seconds:.2f} s per {unit} = {_minutes(minutes)} (~{_minutes(minutes / parallel)} with "
            f"{parallel} {how}); measured from {rate.source}", minutes)


def not_estimated(ids: Sequence[str], shown: int = 3) -> str:
    """The jobs without an estimate, each stage's first ``shown`` by name and the rest counted (``diagnose/a,
    diagnose/b, diagnose/c and 33 more diagnose jobs``)."""
    stages: dict[str, list[str]] = {}
    for job in ids:
        stages.setdefault(job.split("/")[0], []).append(job)
    parts = []
    for stage, found in stages.items():
        more = len(found) - shown
        parts.append(", ".join(found[:shown]) + (f" and {more} more {stage} jobs" if more > 1 else
                                                  f", {found[shown]}" if more == 1 else ""))
    return ", ".join(parts)


def estimate(spec: ExperimentSpec, layout: Layout, jobs: Sequence[StatusJob]) -> list[str]:
    """The estimated cost of the jobs not done (trainings and evaluations; see the module docstring), each with
    where its rate was measured; ``[]`` when nothing is left."""
    open_jobs = [j for j in jobs if j.state != "done"]
    lines: list[str] = []
    minutes = 0.0
    trainings = [j.id.split("/")[1] for j in open_jobs if j.stage == "train"]
    if trainings:
        left = sum(max(0, spec.runs[run].config.steps - steps_done(layout, run)) for run in trainings)
        line, cost = _cost("training", len(trainings), left, "step", step_rate(spec, layout),
                           min(len(trainings), spec.resources.trainings_at_a_time), "at a time")
        lines, minutes = [*lines, line], minutes + cost
    evaluations = [j.id.split("/")[1:] for j in open_jobs if j.stage == "eval" and j.id.count("/") == 2]
    if evaluations:
        left = sum(episodes_left(spec, layout, name, split) for name, split in evaluations)
        line, cost = _cost("evaluation", len(evaluations), left, "episode", episode_rate(spec, layout),
                           spec.evaluation.workers, "worker(s)")
        lines, minutes = [*lines, line], minutes + cost
    rates = diagnosis_rates(jobs)
    diagnoses: dict[str, list[str]] = {}
    for job in open_jobs:
        if job.stage == "diagnose" and diagnosis_kind(job.id) in rates:
            diagnoses.setdefault(diagnosis_kind(job.id), []).append(job.id)
    parallel = spec.resources.trainings_at_a_time * spec.resources.threads_each  # the engine's diagnosis slots
    for kind, found in diagnoses.items():
        line, cost = _cost(f"diagnosis ({kind})", len(found), len(found), "job", rates[kind],
                           min(len(found), parallel), "at a time")
        lines, minutes = [*lines, line], minutes + cost
    estimated = {job for found in diagnoses.values() for job in found}
    others = [j.id for j in open_jobs if (j.stage in ("data", "ground", "diagnose") or j.id == "eval/zoo")
              and j.id not in estimated]
    if others:
        lines.append(f"  not estimated: {not_estimated(others)}")
    if not lines:
        return []
    return [f"estimate of what is left: {_minutes(minutes)} of CPU work" if minutes else
            "estimate of what is left:", *lines]
