"""The experiment engine: idempotent stages data → ground → train → export → eval → diagnose → report.

Each stage is a list of :class:`Job` s planned from the spec and the files on disk: a job whose outputs exist
is done and never runs again (a resumed run, a rerun, a fresh clone after :func:`~abm.experiments.state.restore`);
a job that cannot run yet says why (no benchmark CLIP, not trained yet). What a job does is a typed job
(:mod:`abm.experiments.jobs`) that its own process runs (``python -m abm.experiments.jobs OUT/jobs/JOB.json``):
the engine builds no command line. Trainings run N at a time × T threads (:mod:`abm.experiments.scheduler`), each
continuing from its last checkpoint (its config resumes) or, on a fresh clone, from the committed carry, and is
exported the moment it ends when the run has the export stage too; evaluations skip finished episodes (an
evaluation resumes by itself).

::

    engine = Engine(load_spec("paper_tables"), root=Path("."))
    engine.run(["train", "export"])        # what is left of those stages
    for job in engine.status(): ...       # done / running / left / blocked, with times
"""

from __future__ import annotations

import json
import logging
import os
import re
import socket
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from abm.errors import ConfigError
from abm.evaluation.diagnose.destination_grounding import DestinationGrounding
from abm.evaluation.diagnose.keyframe_accuracy import KeyframeAccuracy
from abm.evaluation.diagnose.request import DiagnosisRequest
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.evaluation.session import EvalRequest
from abm.evaluation.settings import EvalSettings
from abm.experiments.jobs import (
    DataJob,
    DiagnoseJob,
    EvaluationJob,
    ExportJob,
    GroundJob,
    TrainJob,
    TypedJob,
    ZooEvalJob,
)
from abm.experiments.report import held_back, keep_training_log, write_report, zoo_index
from abm.experiments.scheduler import Command, LocalRunner, RayRunner, Runner, Source
from abm.experiments.spec import EXTRA_STAGES, ORACLE_MASK, STAGES, DestinationGroundingSpec, ExperimentSpec
from abm.experiments.state import (
    DESTINATION_GROUNDING_JOB,
    CarryError,
    Layout,
    carry_unfinished,
    checkpoints,
    drop_carry,
    finished_training,
    folder_busy,
    folder_holder,
    holder_pid,
    job_events,
    keep,
    kept_pairs,
    last_logged_step,
    log_job,
    pid_alive,
    record_machine,
    restore,
    restore_evaluation,
    restore_training,
    span_minutes,
    stamp,
)
from abm.experiments.status import kept_minutes
from abm.files import FolderBusyError, FolderLock, sha256_file
from abm.grounding.config import GROUNDERS
from abm.policy.config import PolicyConfig
from abm.zoo import ZooError

LOG = logging.getLogger("abm")
DONE, RUNNING, LEFT, BLOCKED, FAILED = "done", "running", "left", "blocked", "failed"


@dataclass
class Job:
    """One unit of work of a stage.

    Attributes:
        id: ``STAGE/NAME[/SPLIT]`` (``train/abm_oracle``, ``eval/abm_clip/seen``).
        stage: its stage.
        work: what it does, as a typed job (:mod:`abm.experiments.jobs`) its own process runs (``None``: done in
            the engine's process, or blocked before it can be said).
        state: ``done``, ``left``, ``blocked`` (cannot run yet: see ``note``), ``running`` or ``failed``.
        note: progress or the reason it is blocked.
        threads: torch threads (trainings).
        folder: the folder it writes (a live lock on it means it is running).
        before: called right before it starts (restores carried state, writes the run's recipe).
        after: called with its exit code once it ended.
        minutes: how long it ran (done) or runs (running), when known.
    """

    id: str
    stage: str
    work: TypedJob | None = None
    state: str = LEFT
    note: str = ""
    threads: int | None = None
    folder: Path | None = None
    before: Callable[[], None] | None = field(default=None, repr=False)
    after: Callable[[int], None] | None = field(default=None, repr=False)
    minutes: float | None = None


def training_steps(spec: ExperimentSpec) -> int:
    """Optimiser steps of every run: the spec's, else its recipe's, else the training default (a spec's runs
    cannot set their own: :data:`abm.experiments.spec.ENGINE_TRAIN_FIELDS`)."""
    return next(iter(spec.runs.values())).config.steps


_PROGRESS = re.compile(r"^\s*(\d+%\||[\w/ .-]*:\s*\d+%)|[█▏▎▍▌▋▊▉]")  # a progress bar's line


def last_line(log: Path, tail_bytes: int = 65536) -> str:
    """The last line of a job's log that says something (not blank, not a progress bar): why it failed, as
    ``abm: error: ...`` or an exception's last line; ``""`` when it has none."""
    try:
        with log.open("rb") as f:
            f.seek(max(0, f.seek(0, 2) - tail_bytes))
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return ""
    lines = [" ".join(line.split()) for line in re.split(r"[\r\n]+", text)]
    said = [line for line in lines if line and not _PROGRESS.search(line)]
    return said[-1][:300] if said else ""


def runs_job(pid: int, job_file: str) -> bool:
    """Whether process ``pid`` runs the job written to ``job_file`` (as the job's command line names it,
    ``python -m abm.experiments.jobs JOB_FILE``: :meth:`Source.job`; read from ``/proc/PID/cmdline``), so a pid the
    system gave again to another process is not taken for the job; without ``/proc``, a live pid is taken for it."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode("utf-8", "replace").split("\0")
    except OSError:
        return True
    return job_file in argv


def shown(work: TypedJob | None) -> str:
    """A job as ``abm experiment run --dry-run`` prints it: the ``abm`` command that does the same (run by this
    interpreter), else the job itself (JSON)."""
    if work is None:
        return ""
    words = work.command()
    return " ".join([sys.executable, "-m", "abm.cli", *words]) if words else json.dumps(work.to_dict())


def evaluated_together(jobs: Sequence[Job]) -> list[Job]:
    """``jobs`` with the evaluations of each split (the same workers and backend) run as one job: the first one's,
    whose work evaluates the others too (:attr:`abm.experiments.jobs.EvaluationJob.together`), so every scene is
    built once for all the split's models (:mod:`abm.evaluation.scene_cache`); each evaluation keeps its own
    folder, so what is done, carried or restored is still per model. The first job runs the others' ``before``
    and ``after`` with its own and sets their state; its log holds all of them. Other jobs are left as they are."""
    kept: list[Job] = []
    groups: dict[tuple[Any, ...], list[Job]] = {}
    for job in jobs:
        work = job.work
        if isinstance(work, EvaluationJob) and len(work.request.splits) == 1 and not work.together:
            r = work.request
            key = (r.splits[0], r.workers, r.backend, r.ray_address)
            if key not in groups:
                kept.append(job)
            groups.setdefault(key, []).append(job)
        else:
            kept.append(job)
    for lead, *others in groups.values():
        if not others:
            continue
        assert isinstance(lead.work, EvaluationJob)
        lead.work = replace(lead.work, together=tuple(o.work.request for o in others
                                                      if isinstance(o.work, EvaluationJob)))
        members = [lead, *others]
        befores = [j.before for j in members if j.before is not None]
        afters = [(j, j.after) for j in members]

        def before(befores: list[Callable[[], None]] = befores) -> None:
            for call in befores:
                call()

        def after(code: int, afters: list[tuple[Job, Callable[[int], None] | None]] = afters) -> None:
            for job, call in afters:
                if call is not None:
                    call(code)
                job.state = DONE if code == 0 else FAILED

        lead.before, lead.after = before, after
    return kept


class Engine:
    """Plans and runs the stages of one experiment.

    Args:
        spec: the experiment.
        root: the folder the spec's paths start from (the checkout); commands run there.
        out: the working folder (default: the spec's, under ``root``).
        source: the code the jobs run (default: this checkout, :meth:`Source.here`).
        runs: only these runs (and their variants and diagnoses); default all.
        backend: ``local`` (subprocesses) or ``ray`` (trainings and evaluations on a Ray cluster).
        ray_address: the cluster (``None``: a local Ray).
        runner: the runner of the trainings and evaluations (default: from ``backend``; tests pass their own).
        clip_model: the CLIP weights the runs that need one use (a hub name or a folder), instead of the spec's
            ``clip`` folder (``abm quickstart`` passes the one it found).
        threads: torch threads of every training, instead of the spec's ``resources.threads_each``; also keeps a
            training left alone at that many (by default it takes the idle slots' threads too), for when another
            run shares the machine.
    """

    def __init__(self, spec: ExperimentSpec, root: Path, out: Path | None = None, source: Source | None = None,
                 runs: Sequence[str] | None = None, backend: str = "local", ray_address: str | None = None,
                 runner: Runner | None = None, clip_model: str | None = None, threads: int | None = None) -> None:
        if threads is not None and threads < 1:
            raise ConfigError(f"--threads {threads}: a training needs at least one thread")
        unknown = [r for r in runs or () if r not in spec.runs]
        if unknown:
            raise ConfigError(f"--runs {' '.join(unknown)}: not a run of {spec.name} (its runs: "
                              f"{', '.join(spec.runs)})")
        self.spec, self.root = spec, root
        self.layout = Layout.of(spec, root, out)
        self.source = source or Source.here()
        self.selected = [r for r in spec.run_names() if not runs or r in runs]
        self.backend, self.ray_address = backend, ray_address
        self.runner = runner
        self.clip_model = clip_model
        self.threads = threads
        self.steps = training_steps(spec)
        self._events: dict[str, list[dict[str, Any]]] = {}
        self._open: set[str] = set()  # jobs started and not ended yet
        self._export_with_training = False  # export each training as it ends (run() with train and export)
        self._kept = dict(kept_pairs(spec, self.layout))
        self._zoo_checked: set[tuple[str, int, int]] = set()  # zoo files matched to their index entry

    # ------------------------------------------------------------------------------------------- helpers
    def rel(self, path: Path) -> str:
        """A path as the commands name it: relative to the root (they run there), so no machine's folder
        enters a run's config.json or a report."""
        return self.layout.show(path)

    def have(self, path: Path) -> bool:
        """Whether a result file is in OUT, or committed in KEPT (a run restores it before it plans)."""
        copy = self._kept.get(path)
        return path.is_file() or (copy is not None and copy.is_file())

    def has_clip(self) -> bool:
        clip = self.layout.clip
        return self.clip_model is not None or (clip is not None and (clip / "config.json").is_file())

    def clip_arg(self) -> str:
        """The ``--clip-model`` of the commands: the given CLIP, else the spec's folder (root-relative)."""
        if self.clip_model is not None:
            return self.clip_model
        return self.rel(self.layout.clip) if self.layout.clip is not None else ""

    def exported(self, run: str) -> bool:
        """Whether ``run``'s zoo file is there; one the zoo index lists must match the size and sha256 it records
        (:meth:`check_zoo_file`), or the engine would skip a training whose weights it does not have."""
        if self.layout.zoo is None or not self.layout.zoo_file(run).is_file():
            return False
        self.check_zoo_file(run)
        return True

    def check_zoo_file(self, run: str) -> None:
        """Check ``run``'s zoo file against the size and sha256 its entry in ``ZOO/index.json`` records (no entry:
        an export whose index is not written yet, accepted), each file hashed once while its size and
        modification time stay the same.

        Raises:
            ZooError: the file's size or sha256 is not what the index records (a partial copy, another file).
        """
        assert self.layout.zoo is not None
        file = self.layout.zoo_file(run)
        stat = file.stat()
        key = (str(file), stat.st_size, stat.st_mtime_ns)
        if key in self._zoo_checked:
            return
        index = self.layout.zoo / "index.json"
        listed = json.loads(index.read_text()) if index.is_file() else []
        entry = next((e for e in listed if isinstance(e, dict) and e.get("name") == self.spec.zoo_name(run)), None)
        if entry is not None and (entry.get("size_bytes", stat.st_size) != stat.st_size
                                  or entry.get("sha256", "") not in ("", sha256_file(file))):
            raise ZooError(f"{file} is not the model {index} records for {run} ({stat.st_size} bytes, the index says "
                           f"{entry.get('size_bytes')}; or another sha256): restore it with git checkout, or remove "
                           f"it and its index entry to train {run} again")
        self._zoo_checked.add(key)

    def trained(self, run: str) -> bool:
        """Finished: exported, or its latest checkpoint holds the last step (the step it records, not its name) or
        says the run stopped there, its curve flat (``abm train --stop-when-flat``)."""
        if self.exported(run):
            return True
        found = checkpoints(self.layout.run_dir(run))
        return bool(found) and finished_training(found[-1][1], self.steps)

    def model(self, run: str) -> Path | None:
        """What evaluations load: the zoo file (``from_zoo``) or the run folder, once it is finished."""
        if self.spec.evaluation.from_zoo:
            return self.layout.zoo_file(run) if self.exported(run) else None
        return self.layout.run_dir(run) if self.trained(run) else None

    def needs_clip(self, run: str) -> bool:
        return self.spec.runs[run].needs_clip

    def _ran(self, job: Job) -> bool:
        """Whether the job log has a successful end of ``job`` (jobs without an output file to check)."""
        return any(e["event"] == "end" and e.get("rc") == 0 for e in self._events.get(job.id, []))

    # ---------------------------------------------------------------------------------------------- plans
    def plan(self, stage: str) -> list[Job]:
        """The jobs of ``stage`` as the files on disk stand now."""
        self._events = job_events(self.layout)
        planner = {"data": self._data, "ground": self._ground, "train": self._train, "export": self._export,
                   "eval": self._eval, "diagnose": self._diagnose, "report": self._report,
                   "carry": self._carry}[stage]
        jobs = planner()
        if self.spec.finished and stage not in ("report", "carry"):  # finished and kept: only its report runs
            for job in jobs:
                job.state, job.note, job.before, job.after = DONE, "finished (kept)", None, None
        return jobs

    def _data(self) -> list[Job]:
        d = self.spec.data
        folder = self.layout.data
        have = {t: len(list((folder / t / d.split).glob("*.h5"))) if (folder / t / d.split).is_dir() else 0
                for t in d.tasks}
        short = {t: n for t, n in have.items() if n < d.episodes}
        needed = any(not self.trained(r) for r in self.selected)
        work = DataJob(tuple(d.tasks), d.split, d.episodes, Path(self.rel(folder)), workers=d.workers,
                            seed=d.seed, resolution=d.resolution, backend=self.backend, ray_address=self.ray_address)
        job = Job("data", "data", work, folder=None)
        if not short:
            job.state, job.note = DONE, f"{sum(have.values())} demonstrations"
        elif not needed:
            job.state, job.note = DONE, "not needed: every selected run is trained"
        else:
            job.note = f"{sum(min(n, d.episodes) for n in have.values())}/{d.episodes * len(d.tasks)} demonstrations"
        return [job]

    def _ground(self) -> list[Job]:
        jobs = []
        tasks = self.spec.training.tasks or self.spec.data.tasks
        for kind in ("masks", "features"):
            users = [r for r in self.selected if self.spec.runs[r].cache == kind]
            if not users:
                continue
            policy, default = self.spec.runs[users[0]].config.policy, PolicyConfig()
            cache = self.layout.cache(kind)
            work = GroundJob(
                Path(self.rel(self.layout.data)), Path(self.rel(cache)), self.clip_arg(), tuple(tasks),
                features=kind == "features",
                workspace_center=policy.workspace_center if policy.workspace_center != default.workspace_center
                else None,
                workspace_size=policy.workspace_size if policy.workspace_size != default.workspace_size else None)
            job = Job(f"ground/{kind}", "ground", work, folder=cache)
            if all(self.trained(r) for r in users):
                job.state, job.note = DONE, "not needed: its runs are trained"
            elif self._ran(job) and cache.is_dir():
                job.state = DONE
            elif not self.has_clip():
                job.state, job.note = BLOCKED, f"no benchmark CLIP in {self.rel(self.layout.clip or self.root)}"
            jobs.append(job)
        return jobs

    def recipe(self, run: str) -> dict[str, Any]:
        """The run's whole recipe (``abm train --config``): what the spec trains for it
        (:meth:`ExperimentSpec.train_config`) as a recipe, with its grounding cache."""
        config = self.spec.train_config(run, self.layout, self.clip_model)
        return {**config.to_recipe(), **({"cache_dir": str(config.cache_dir)} if config.cache_dir else {})}

    def _train(self) -> list[Job]:
        jobs = []
        for run in self.spec.training_order():
            if run not in self.selected:
                continue
            folder = self.layout.run_dir(run)
            recipe_file = self.layout.recipe(run)
            work = TrainJob(self.spec.train_config(run, self.layout, self.clip_model), Path(self.rel(recipe_file)))
            job = Job(f"train/{run}", "train", work,
                      threads=self.slots("train")[1], folder=folder)
            step = last_logged_step(folder)
            if self.trained(run):
                job.state = DONE
                job.note = "exported" if self.exported(run) else (
                    f"{step}/{self.steps} steps: stopped, its curve flat" if step is not None and step < self.steps
                    else f"{self.steps} steps")
            elif self.needs_clip(run) and not self.has_clip():
                job.state, job.note = BLOCKED, f"no benchmark CLIP in {self.rel(self.layout.clip or self.root)}"
            else:
                job.note = f"step {step}/{self.steps}" if step is not None else (
                    "continues from the carry" if self.layout.carry and (self.layout.carry / run).is_dir() else "")

                def before(run: str = run, recipe_file: Path = recipe_file) -> None:
                    if restore_training(self.layout, run):
                        LOG.info("%s: continuing from the checkpoint carried in %s", run,
                                 self.rel(self.layout.carry or self.root))
                    recipe_file.parent.mkdir(parents=True, exist_ok=True)
                    recipe_file.write_text(f"# abm experiment run {self.spec.name}: the recipe of run {run}\n"
                                           + yaml.safe_dump(self.recipe(run), sort_keys=False))

                job.before = before
                job.after = lambda code, run=run: self._export_now(run) if code == 0 else None
            jobs.append(job)
        return jobs

    def _export_now(self, run: str) -> None:
        """Export ``run`` the moment its training ends, when this invocation runs the export stage too: its
        sibling may train for hours yet, and until the zoo file exists a session that stops loses the finished
        model on a fresh machine (and its evaluations cannot start). The export stage then finds it done."""
        if not self._export_with_training:
            return
        todo = [job for job in self._export() if job.id == f"export/{run}" and job.state == LEFT]
        if todo:
            LOG.info("export/%s: its training finished, exported now", run)
            LocalRunner().run(self._commands(todo), self.source, 1, on_start=self._start)

    def _export(self) -> list[Job]:
        if self.layout.zoo is None:
            return []
        jobs = []
        for run in self.selected:
            target = self.layout.zoo_file(run)
            job = Job(f"export/{run}", "export", ExportJob(Path(self.rel(self.layout.run_dir(run))),
                                                                Path(self.rel(target)), "bfloat16"))
            if target.is_file():
                job.state = DONE
            elif not self.trained(run):
                job.state, job.note = BLOCKED, "not trained yet"
            else:
                def after(code: int, run: str = run) -> None:
                    if code == 0:
                        if (self.layout.run_dir(run) / "log.csv").is_file():  # its loss curve, for a fresh clone
                            keep_training_log(self.layout.run_dir(run), self.layout.kept / f"training_{run}.csv")
                        drop_carry(self.layout, run)
                        self.write_zoo_index()

                job.after = after
            jobs.append(job)
        return jobs

    def write_zoo_index(self) -> None:
        """(Re)write ``ZOO/index.json`` (every exported model of the spec and the benchmark CLIP)."""
        if self.layout.zoo is not None:
            entries = zoo_index(self.spec, self.layout)
            (self.layout.zoo / "index.json").write_text(json.dumps(entries, indent=2) + "\n")

    def _variant_base(self, name: str) -> str:
        return next((v.run for v in self.spec.evaluation.variants if v.name == name), name)

    def _eval(self) -> list[Job]:
        ev = self.spec.evaluation
        jobs = []
        names = [*self.selected, *(v.name for v in ev.variants if v.run in self.selected)]
        for name in names:
            base = self._variant_base(name)
            variant = next((v for v in ev.variants if v.name == name), None)
            for split in ev.splits:
                if split.runs is not None and name not in split.runs:
                    continue
                folder = self.layout.eval_dir(name, split.split)
                model = self.model(base)
                variant_clip = bool(variant and variant.grounder and GROUNDERS[variant.grounder].clip)
                settings = EvalSettings(
                    device=ev.device, grounder=variant.grounder or None if variant is not None else None,
                    resolution=self.spec.data.resolution, max_steps=ev.max_steps,
                    clip_model=self.clip_arg() if variant_clip and self.clip_arg() else None,
                    expert_keyframes=variant.expert_keyframes or None if variant is not None else None)
                request = EvalRequest((Path(self.rel(model)),) if model else (), tasks=tuple(split.tasks),
                                      splits=(split.split,), episodes=ev.episodes, repeats=ev.repeats,
                                      workers=ev.workers, gifs=ev.gifs, out=Path(self.rel(folder)), settings=settings)
                job = Job(f"eval/{name}/{split.split}", "eval", EvaluationJob(request) if model else None,
                          folder=folder)
                if self.have(folder / "results.json"):
                    job.state = DONE
                elif model is None:
                    job.state, job.note = BLOCKED, "not exported yet" if ev.from_zoo else "not trained yet"
                elif (self.needs_clip(base) or variant_clip) and not self.has_clip():
                    job.state, job.note = BLOCKED, "no benchmark CLIP"
                else:
                    outcomes = folder / "outcomes.jsonl"
                    if outcomes.is_file():
                        job.note = f"{len(outcomes.read_text().splitlines())} outcomes so far"

                    def before(name: str = name, split: str = split.split, model: Path = model) -> None:
                        restore_evaluation(self.layout, name, split, model)

                    def after(code: int, name: str = name) -> None:
                        if code == 0 and all((f / "results.json").is_file()
                                             for f in (self.layout.out / "eval" / name).iterdir() if f.is_dir()):
                            drop_carry(self.layout, "eval", name)

                    job.before, job.after = before, after
                jobs.append(job)
        if ev.zoo_eval and self.layout.zoo is not None:
            jobs.append(self._zoo_eval())
        return jobs

    def _zoo_eval(self) -> Job:
        folder = self.layout.zoo_eval
        assert self.layout.zoo is not None
        # the spec's own models by name: before a README gate opens, abm zoo eval's default is an earlier edition's
        models = tuple(self.spec.zoo_name(r) for r in self.spec.evaluation.zoo_eval)
        job = Job("eval/zoo", "eval", ZooEvalJob(Path(self.rel(self.layout.zoo)), Path(self.rel(folder)),
                                                 models=models), folder=folder / "seen")
        missing = [r for r in self.spec.evaluation.zoo_eval if not self.exported(r)]
        if self.have(folder / "seconds"):
            job.state = DONE
        elif missing:
            job.state, job.note = BLOCKED, f"waits for {', '.join(missing)} in the zoo"
        else:
            started: list[float] = []
            job.before = lambda: started.append(time.time())

            def after(code: int) -> None:
                if code == 0 and started:
                    (folder / "seconds").write_text(f"{round(time.time() - started[0])}\n")

            job.after = after
        return job

    def _diagnose(self) -> list[Job]:
        d = self.spec.diagnose
        if d is None:
            return []
        found = []
        tasks = d.tasks or self.spec.training.tasks or self.spec.data.tasks
        for name in self.spec.diagnoses():
            base = name.removesuffix(ORACLE_MASK)
            if base not in self.selected:
                continue
            model = self.layout.run_dir(base) if d.steps and self.trained(base) else self.model(base)
            oracle = name.endswith(ORACLE_MASK)
            out = self.layout.diagnosis(name)
            request = KeyframeAccuracy(
                (Path(self.rel(model)),), tuple(tasks), Path(self.rel(out)), splits=tuple(d.splits),
                episodes=d.episodes, resolution=self.spec.data.resolution, steps=tuple(d.steps),
                grounder="oracle" if oracle else None) if model else None
            found.append(self._diagnosis_job(f"diagnose/{name}", request, out,
                                             clip=self.needs_clip(base) and not oracle))
        probe, skill_tasks = d.skill_text, self.spec.training.tasks or self.spec.data.tasks
        for run, task in self.spec.probes():  # the skill-text probe: each probed run on each task
            if probe is None or run not in self.selected:
                continue
            model, out = self.model(run), self.layout.skill_text(run, task)
            probed = SkillTextProbe(Path(self.rel(model)), task, tuple(skill_tasks), Path(self.rel(out)),
                                    keyframe=probe.kind, split=probe.split, episodes=probe.episodes,
                                    resolution=self.spec.data.resolution) if model else None
            found.append(self._diagnosis_job(f"diagnose/skill_text/{run}/{task}", probed, out,
                                             clip=self.needs_clip(run)))
        if d.destination_grounding is not None:  # of the spec's CLIP grounder, not of a run: whatever --runs says
            found.append(self._destination_grounding(d.destination_grounding, tasks))
        return found

    def _destination_grounding(self, spec: DestinationGroundingSpec, tasks: Sequence[str]) -> Job:
        """The diagnosis of the spec's CLIP grounder on each task's destination beside its target (one job)."""
        out = self.layout.destination_grounding
        request = DestinationGrounding(self.clip_arg() or None, Path(self.rel(out)), tasks=tuple(spec.tasks or tasks),
                                       splits=spec.splits, episodes=spec.episodes,
                                       resolution=self.spec.data.resolution)
        return self._diagnosis_job(DESTINATION_GROUNDING_JOB, request, out, clip=True)

    def _diagnosis_job(self, job_id: str, request: DiagnosisRequest | None, out: Path, clip: bool) -> Job:
        """A diagnosis job (``request``: ``None`` until its model is trained or exported); done once ``out`` is
        there (or kept), blocked until its model is there, or without the benchmark CLIP it needs (``clip``)."""
        job = Job(job_id, "diagnose", DiagnoseJob(request) if request is not None else None)
        if self.have(out):
            job.state = DONE
        elif request is None:
            job.state = BLOCKED
            job.note = "not exported yet" if self.spec.evaluation.from_zoo else "not trained yet"
        elif clip and not self.has_clip():
            job.state, job.note = BLOCKED, "no benchmark CLIP"
        return job

    def _report(self) -> list[Job]:
        return [Job("report", "report", note=f"writes {self.spec.report.document or self.spec.report.readme}")]

    def _carry(self) -> list[Job]:
        return [Job("carry", "carry", note=f"unfinished work into {self.rel(self.layout.carry)}"
                    if self.layout.carry else "this experiment keeps no carry")]

    # ------------------------------------------------------------------------------------------- running
    def _runner(self, cpus: int) -> Runner:
        if self.runner is not None:
            return self.runner
        if self.backend == "ray":
            return RayRunner(self.ray_address, cpus)
        return LocalRunner(lend_idle_threads=self.threads is None)

    def _commands(self, jobs: Iterable[Job]) -> list[Command]:
        commands = []
        for job in jobs:
            assert job.work is not None
            file = self.layout.job_file(job.id)

            def after(code: int, job: Job = job) -> None:
                self._open.discard(job.id)
                log_job(self.layout, job.id, "end", rc=code)
                if job.after is not None:
                    job.after(code)
                job.state = DONE if code == 0 else FAILED

            def before(job: Job = job, file: Path = file) -> None:
                if job.before is not None:
                    job.before()
                assert job.work is not None
                job.work.write(file)

            commands.append(Command(job.id, self.source.job(self.rel(file)), self.layout.log(job.id), self.root,
                                    job.threads, after, before, job.work))
        return commands

    def _start(self, command: Command, pid: int | None) -> None:
        self._open.add(command.job)
        log_job(self.layout, command.job, "start", pid=pid, backend=self.backend)
        LOG.info("  %s  (log: %s)", command.job, self.rel(command.log))

    def run(self, stages: Sequence[str] = STAGES, dry_run: bool = False) -> int:
        """Run what is left of ``stages`` (in the engine's order); returns 0, or 1 when a job failed (the stages
        after a failed one are not run). An interrupt carries the unfinished work and re-raises."""
        unknown = [s for s in stages if s not in STAGES + EXTRA_STAGES]
        if unknown:
            raise ConfigError(f"--stages {' '.join(unknown)}: unknown (stages: {', '.join(STAGES + EXTRA_STAGES)})")
        order = [s for s in (*STAGES, *EXTRA_STAGES) if s in stages]
        if "carry" in order and self.layout.carry is None:
            raise ConfigError(f"--stages carry: {self.spec.name} keeps no carry (its spec has no carry: folder), so "
                              "there is nothing to carry into; add carry: FOLDER to the spec, or leave carry out")
        self._export_with_training = not dry_run and "train" in order and "export" in order
        if dry_run:
            return 0 if all(self._run_stage(stage, dry_run) for stage in order) else 1
        lock = FolderLock(self.layout.out, f"abm experiment run {self.spec.name}")
        try:
            lock.__enter__()
        except FolderBusyError:
            holder = folder_holder(self.layout.out) or "another process"
            raise FolderBusyError(f"abm experiment run {self.spec.name}: already running ({holder_pid(holder)}) in "
                                  f"{self.rel(self.layout.out)}; nothing started: one engine per working folder (see "
                                  f"abm experiment status {self.spec.name}; --out DIR for a second one)") from None
        try:
            return self._run_locked(order)
        finally:
            lock.__exit__(None, None, None)

    def _run_locked(self, order: Sequence[str]) -> int:
        """:meth:`run`'s stages, this engine alone in the working folder."""
        copied = restore(self.spec, self.layout)
        if copied:
            LOG.info("restored %d finished result file(s) from %s", copied, self.rel(self.layout.kept))
        try:
            for stage in order:
                if not self._run_stage(stage, False):
                    self.carry()
                    return 1
        except BaseException:
            self.carry()
            raise
        return 0

    def running_elsewhere(self, job: Job) -> str | None:
        """``pid N`` of a live process that runs ``job`` already (a job an engine stopped with ``kill -9`` left
        running: its folder's lock, or its last start in the job log on this host), else ``None``."""
        holder = folder_holder(job.folder) if job.folder is not None else None
        if holder is not None:
            return holder_pid(holder)
        events = self._events.get(job.id, [])
        starts = [e for e in events if e["event"] == "start"]
        if self._live(starts, [e for e in events if e["event"] == "end"]) and starts[-1]["pid"] != os.getpid() \
                and runs_job(starts[-1]["pid"], self.rel(self.layout.job_file(job.id))):
            return f"pid {starts[-1]['pid']}"
        return None

    def slots(self, stage: str) -> tuple[int, int]:
        """``(jobs at a time, CPUs each)`` of a stage: trainings as the resources say; evaluations (``workers``
        processes each) and diagnoses (one each) as many as fit the trainings' CPUs; the rest one at a time (the
        generator has its own workers; ``abm export`` locks the zoo folder it writes)."""
        res = self.spec.resources
        threads = self.threads or res.threads_each
        cpus = res.trainings_at_a_time * threads
        if stage == "train":
            return res.trainings_at_a_time, threads
        if stage == "eval":
            workers = self.spec.evaluation.workers
            return max(1, cpus // workers), workers
        if stage == "diagnose":
            return max(1, cpus), 1
        return 1, 1

    def carry(self, strict: bool = False) -> list[str]:
        """Carry the unfinished trainings and evaluations (see :func:`carry_unfinished`); a carry folder holding
        files the carry did not write raises :class:`CarryError` (``strict``: ``--stages carry``) or is said in
        one line (the carry after a failed or stopped stage, which must not hide why it stopped). A carried
        training that nothing needs any more (:meth:`served`) is removed. Every finished result is kept
        (:func:`keep`, as the report stage keeps them): an evaluation or diagnosis that ended in a session stopped
        before its report is neither carried (it is finished) nor run again on a fresh clone, and the session's stage
        times and machine count there too."""
        served = self.served()
        keep(self.spec, self.layout)
        try:
            copied = [name for name in carry_unfinished(self.spec, self.layout) if name not in served]
        except CarryError as err:
            if strict:
                raise
            LOG.error("carry: %s", err)
            return []
        for run in served:
            drop_carry(self.layout, run)
            LOG.info("carry: removed %s's carried checkpoint (its evaluations and diagnoses are kept)", run)
        if copied:
            LOG.info("carried %s into %s (commit it to continue elsewhere)", ", ".join(copied),
                     self.rel(self.layout.carry or self.root))
        elif strict:
            LOG.info("carry: nothing unfinished to carry into %s", self.rel(self.layout.carry or self.root))
        return copied

    def served(self) -> list[str]:
        """The carried trainings nothing needs any more: runs of a spec without a zoo (an exported run's carry goes
        with its export) whose every evaluation (its variants' too) and diagnosis is done and kept."""
        if self.layout.carry is None or self.layout.zoo is not None:
            return []
        users: dict[str, list[str]] = {}
        for job in (*self.plan("eval"), *self.plan("diagnose")):
            if job.id == DESTINATION_GROUNDING_JOB:  # of the grounder: no run's
                continue
            name = job.id.split("/")[2 if job.id.startswith("diagnose/skill_text/") else 1]
            users.setdefault(self._variant_base(name.removesuffix(ORACLE_MASK)), []).append(job.state)
        return [run for run in self.spec.runs if (self.layout.carry / run).is_dir() and users.get(run)
                and all(state == DONE for state in users[run])]

    def _run_stage(self, stage: str, dry_run: bool) -> bool:
        jobs = self.plan(stage)
        if stage == "report":
            if dry_run:
                LOG.info("report: would write %s", self.spec.report.document or self.spec.report.readme)
                return True
            keep(self.spec, self.layout)
            report = write_report(self.spec, self.layout)
            written = [self.spec.report.document] if self.spec.report.document else []
            if self.spec.report.readme and not report.waits:
                names = [self.spec.report.block, *self.spec.report.blocks]
                written.append(f"the {' and '.join(names)} block{'s' if len(names) > 1 else ''} of "
                               f"{self.spec.report.readme}")
            LOG.info("report: wrote %s", " and ".join(written) or "no document")
            if report.waits:  # the README gate (report.readme_when) is closed
                LOG.info("report: left %s unchanged until %s", held_back(self.spec, self.layout), report.waits)
            return True
        if stage == "carry":
            if not dry_run:
                self.carry(strict=True)
            return True
        todo = [j for j in jobs if j.state == LEFT]
        for job in jobs:
            if job.state == BLOCKED:
                LOG.info("%s: skipped (%s)", job.id, job.note)
        busy = {job.id: pid for job in todo if not dry_run and (pid := self.running_elsewhere(job))}
        for job_id, pid in busy.items():
            LOG.error("%s: already running (%s); not started again: wait for it to end (or stop it), then run "
                      "again", job_id, pid)
        todo = [job for job in todo if job.id not in busy]
        if not todo:
            return not busy
        LOG.info("%s: %d job(s)", stage, len(todo))
        if dry_run:
            for job in todo:
                LOG.info("  %s: %s", job.id, shown(job.work))
            return True
        if stage == "eval":
            todo = evaluated_together(todo)
        stamp(self.layout, f"{stage}_start")
        record_machine(self.layout)
        slots, cpus = self.slots(stage)
        runner = self._runner(cpus) if stage in ("train", "eval") else LocalRunner()
        try:
            codes = runner.run(self._commands(todo), self.source, slots, on_start=self._start)
        except BaseException:
            # stopped (Ctrl-C, SIGTERM): close the spans of the jobs that ran and of the stage, so their minutes
            # count; a stopped job stays left (no exit code: it is neither done nor failed)
            for job_id in sorted(self._open):
                log_job(self.layout, job_id, "end", rc=None, stopped=True)
            self._open.clear()
            raise
        finally:
            stamp(self.layout, f"{stage}_end")
        failed = [job for job in todo if codes.get(job.id, 1) != 0]
        for job in failed:
            log = self.layout.log(job.id)
            LOG.error("%s failed (exit code %s): %s (log: %s)", job.id, codes.get(job.id),
                      last_line(log) or "it wrote nothing", self.rel(log))
        return not failed and not busy  # what depends on a job running elsewhere waits for the next run

    # -------------------------------------------------------------------------------------------- status
    def status(self) -> list[Job]:
        """Every job of every stage: done, running, left or blocked, with its minutes when known."""
        jobs: list[Job] = []
        for stage in STAGES:
            for job in self.plan(stage):
                events = self._events.get(job.id, [])
                starts = [e for e in events if e["event"] == "start"]
                ends = [e for e in events if e["event"] == "end"]
                if job.id == "report":
                    others = [j for j in jobs if j.stage != "report"]
                    document = self.root / (self.spec.report.document or self.spec.report.readme)
                    if document.is_file() and all(j.state == DONE for j in others):
                        job.state = DONE
                if job.state != DONE and (
                        (job.folder is not None and folder_busy(job.folder)) or self._live(starts, ends)):
                    job.state = RUNNING
                if job.state == RUNNING and starts:
                    job.minutes = (span_minutes(events) or 0.0) + (time.time() - starts[-1]["time"]) / 60
                elif job.state == DONE:  # this folder's job log, else what is kept (a fresh clone)
                    job.minutes = span_minutes(events)
                    job.minutes = kept_minutes(self.spec, self.layout, job) if job.minutes is None else job.minutes
                elif job.state != DONE and ends and ends[-1].get("rc") not in (0, None) and job.state == LEFT:
                    log = self.layout.log(job.id)
                    job.state, job.note = FAILED, f"exit code {ends[-1]['rc']}: {last_line(log)} (log: {self.rel(log)})"
                jobs.append(job)
        return jobs

    @staticmethod
    def _live(starts: list[dict[str, Any]], ends: list[dict[str, Any]]) -> bool:
        if not starts or (ends and ends[-1]["time"] >= starts[-1]["time"]):
            return False
        last = starts[-1]
        return last.get("host") == socket.gethostname() and isinstance(last.get("pid"), int) and pid_alive(last["pid"])
