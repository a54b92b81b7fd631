"""Where an experiment's files live and what survives a session: :class:`Layout`, the kept outcomes, the carry.

The working folder OUT (``runs/NAME``, never committed) holds the data, run folders, evaluations and
diagnoses. What is finished is kept in the committed folder KEPT (``docs/results/NAME``): evaluation JSON
(``RUN_SPLIT.json``) with every episode's outcome and per-step records, compressed (``RUN_SPLIT_outcomes.jsonl.xz``,
every split of every run and variant), keyframe accuracy (``keyframe_accuracy_NAME.json``), the skill-text probes,
the destination's grounding quality (``destination_grounding.json``), the timed zoo evaluation (its table, seconds
and outcomes: ``zoo_eval_SPLIT_outcomes.jsonl.xz``), the stage times (``times.txt``) and the machines that ran a
stage (``machines.txt``). On a fresh clone :func:`restore`
copies them back into OUT, so nothing finished runs twice and the report has every row.

Unfinished work crosses machines through CARRY (``models/carry``, committed): :func:`carry_unfinished`
copies each unfinished training's latest checkpoint and log (``CARRY/RUN/``) and each unfinished evaluation's
outcomes (``CARRY/eval/RUN/SPLIT/``); the next session continues from them (:func:`restore_training`,
:func:`restore_evaluation`).
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import socket
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.errors import AbmError, OutputError
from abm.evaluation.results import OUTCOME_ARCHIVE, OutcomeLog
from abm.evaluation.settings import ZOO_EVAL_SPLITS
from abm.experiments.spec import ExperimentSpec, SpecError
from abm.files import LOCK_NAME, is_inside, sha256_file, write_text_atomic
from abm.machine import describe_machine

_STEP_FILE = re.compile(r"^step_(\d+)\.pt$")


@dataclass(frozen=True)
class Layout:
    """The paths of one experiment, resolved against the root it runs in.

    Attributes:
        root: the folder every relative path of the spec starts from (the repository checkout).
        out: the working folder.
        kept: the committed outcomes.
        zoo: where finished runs are exported (``None``: no export).
        carry: the committed state of unfinished work (``None``: none kept).
        clip: the benchmark CLIP folder (``None``: no run needs it).
        data: the episode store.
        zoo_suffix: appended to a run's name in the zoo (``ZOO/RUN{zoo_suffix}.pt``).
    """

    root: Path
    out: Path
    kept: Path
    zoo: Path | None
    carry: Path | None
    clip: Path | None
    data: Path
    zoo_suffix: str = ""

    @classmethod
    def of(cls, spec: ExperimentSpec, root: Path, out: Path | None = None) -> Layout:
        """The layout of ``spec`` under ``root`` (``out`` replaces the spec's working folder).

        Raises:
            SpecError: a folder the engine writes in (out, kept, zoo, carry, data.folder) leads outside the root
                (and outside ``out``, when given) once symbolic links are followed, or ``--out`` is the root itself.
        """
        if out is not None and (str(out) == "" or out.resolve() == root.resolve()):
            raise SpecError(f"--out {str(out)!r} is the root itself ({root}): give a working folder inside it, "
                            f"e.g. {spec.out}")
        for key, value in (("out", spec.out if out is None else ""), ("kept", spec.kept), ("zoo", spec.zoo),
                           ("carry", spec.carry), ("data.folder", spec.data.folder or "")):
            # inside the root, or inside the working folder the command line named (abm quickstart --out)
            if value and not any(is_inside(root / value, base) for base in (root, *([out] if out else []))):
                raise SpecError(f"{spec.path}: {key}: {value!r} leads outside the root {root} (through a symbolic "
                                "link): give a folder inside the root")
        work = out if out is not None else root / spec.out
        return cls(root=root, out=work, kept=root / spec.kept, zoo=root / spec.zoo if spec.zoo else None,
                   carry=root / spec.carry if spec.carry else None, clip=root / spec.clip if spec.clip else None,
                   data=root / spec.data.folder if spec.data.folder else work / "data", zoo_suffix=spec.zoo_suffix)

    def run_dir(self, run: str) -> Path:
        return self.out / run

    def zoo_file(self, run: str) -> Path:
        if self.zoo is None:
            raise ValueError("this experiment exports no model (no zoo in its spec)")
        return self.zoo / f"{run}{self.zoo_suffix}.pt"

    def eval_dir(self, name: str, split: str) -> Path:
        return self.out / "eval" / name / split

    def diagnosis(self, name: str) -> Path:
        return self.out / "keyframe_accuracy" / f"{name}.json"

    @property
    def destination_grounding(self) -> Path:
        """The diagnosis of the spec's CLIP grounder on each task's destination and target (one per spec)."""
        return self.out / "destination_grounding.json"

    def skill_text(self, run: str, task: str) -> Path:
        """The skill-text probe of ``run`` on ``task`` (``benchmarks/skill_text_probe.py --out``)."""
        return self.out / "skill_text" / f"{run}_{task}.json"

    def cache(self, kind: str) -> Path:
        return self.out / f"cache_{kind}"

    def recipe(self, run: str) -> Path:
        return self.out / "recipes" / f"{run}.yaml"

    def log(self, job: str) -> Path:
        return self.out / "logs" / (job.replace("/", "_") + ".log")

    def job_file(self, job: str) -> Path:
        """The typed job (:mod:`abm.experiments.jobs`) its process runs, written as it starts."""
        return self.out / "jobs" / (job.replace("/", "_") + ".json")

    @property
    def times(self) -> Path:
        return self.out / "times.txt"

    @property
    def machines(self) -> Path:
        return self.out / "machines.txt"

    @property
    def jobs(self) -> Path:
        return self.out / "jobs.jsonl"

    @property
    def zoo_eval(self) -> Path:
        return self.out / "zoo_eval"

    def show(self, path: Path) -> str:
        """``path`` relative to the root when it is inside (as commands and reports name it; also an absolute
        path under a relative root), else as given."""
        for base, shown in ((self.root, path), (self.root.resolve(), path.resolve())):
            try:
                return shown.relative_to(base).as_posix()
            except ValueError:
                continue
        return str(path)


# ------------------------------------------------------------------------------------------ kept outcomes
def kept_pairs(spec: ExperimentSpec, layout: Layout) -> list[tuple[Path, Path]]:
    """``(file under OUT, its committed copy under KEPT)`` of every finished result the spec can produce."""
    kept, pairs = layout.kept, []
    tables = any(s.kind == "outcome_tables" for s in (*spec.report.summary, *spec.report.details))
    names = [*spec.runs, *(v.name for v in spec.evaluation.variants)]
    for name in names:
        for split in spec.evaluation.splits:
            if split.runs is None or name in split.runs:
                pairs.append((layout.eval_dir(name, split.split) / "results.json",
                              kept / f"{name}_{split.split}.json"))
                # every episode's outcome and per-step records, compressed (abm.evaluation.results.OUTCOME_ARCHIVE)
                pairs.append((layout.eval_dir(name, split.split) / OUTCOME_ARCHIVE,
                              kept / f"{name}_{split.split}_{OUTCOME_ARCHIVE}"))
                if tables:  # the report prints the evaluation's own tables
                    pairs.append((layout.eval_dir(name, split.split) / "results.md",
                                  kept / f"{name}_{split.split}.md"))
    for name in spec.diagnoses():
        pairs.append((layout.diagnosis(name), kept / f"keyframe_accuracy_{name}.json"))
    for run, task in spec.probes():
        pairs.append((layout.skill_text(run, task), kept / f"skill_text_{run}_{task}.json"))
    if spec.diagnose is not None and spec.diagnose.destination_grounding is not None:
        pairs.append((layout.destination_grounding, kept / layout.destination_grounding.name))
    if spec.evaluation.zoo_eval:
        pairs += [(layout.zoo_eval / "results.md", kept / "zoo_eval.md"),
                  (layout.zoo_eval / "seconds", kept / "zoo_eval_seconds.txt")]
        # the timed zoo evaluation's episodes and their per-step records too, compressed, per split
        pairs += [(layout.zoo_eval / split / OUTCOME_ARCHIVE, kept / f"zoo_eval_{split}_{OUTCOME_ARCHIVE}")
                  for split in ZOO_EVAL_SPLITS]
    pairs += [(layout.times, kept / "times.txt"),  # the stage times of every session, added up
              (layout.machines, kept / "machines.txt")]  # every machine that ran a stage
    return pairs


def restore(spec: ExperimentSpec, layout: Layout) -> int:
    """Copy the committed results into OUT where OUT lacks them; returns how many were copied."""
    copied = 0
    for made, copy in kept_pairs(spec, layout):
        if copy.is_file() and not made.exists():
            made.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(copy, made)
            copied += 1
    return copied


def _keep_file(made: Path, copy: Path, merged: bool) -> bool:
    """Write OUT's ``made`` to KEPT's ``copy`` (its lines merged into the copy's when ``merged``: the stage times
    and machines of every session); returns whether the copy changed."""
    if not made.is_file():
        return False
    data = merge_lines(made, copy) if merged else made.read_bytes()
    if copy.is_file() and copy.read_bytes() == data:
        return False
    copy.parent.mkdir(parents=True, exist_ok=True)
    copy.write_bytes(data)
    return True


def keep(spec: ExperimentSpec, layout: Layout) -> int:
    """Copy every finished result of OUT into KEPT (the committed copy); returns how many changed."""
    merged = (layout.times, layout.machines)
    return sum(_keep_file(made, copy, made in merged) for made, copy in kept_pairs(spec, layout))


# ------------------------------------------------------------------------------------------ times, machines
def session() -> str:
    """This engine's session in OUT/times.txt (``HOST:PID``): a stage's end closes its own session's start."""
    return f"{socket.gethostname()}:{os.getpid()}"


def stamp(layout: Layout, event: str, when: float | None = None) -> None:
    """Append ``EVENT SECONDS SESSION`` (``train_start 1795665961 host:4242``) to OUT/times.txt."""
    layout.out.mkdir(parents=True, exist_ok=True)
    with layout.times.open("a") as f:
        f.write(f"{event} {int(time.time() if when is None else when)} {session()}\n")


def stage_minutes(times: Path, *more: Path) -> dict[str, float]:
    """Minutes per stage, summed over every (start, end) pair of one session: a resumed stage counts all its
    sessions, and sessions whose spans interleave (two engines of one experiment, each in its own working folder,
    their times merged into KEPT) each count their own span. Lines without a session (older files) pair as
    they come. ``more`` files add their lines ``times`` lacks (OUT's and KEPT's times together).

    A line ``STAGE_minutes M`` adds ``M`` minutes measured elsewhere (the totals of earlier sessions whose
    run folders did not survive)."""
    return stage_spans(times, *more)[0]


def stage_spans(times: Path, *more: Path) -> tuple[dict[str, float], dict[tuple[str, str], int]]:
    """:func:`stage_minutes`, and the stages started and not ended yet: ``(stage, session) -> start`` (seconds;
    a stage running now, or one whose engine was killed)."""
    total: dict[str, float] = {}
    open_at: dict[tuple[str, str], int] = {}
    lines = times.read_text().split("\n") if times.is_file() else []
    known = set(lines)
    lines += [line for other in more if other.is_file() for line in other.read_text().split("\n")
              if line not in known]
    for line in lines:
        fields = line.split()
        if len(fields) not in (2, 3):
            continue
        key, value, who = fields[0], fields[1], fields[2] if len(fields) == 3 else ""
        stage, _, edge = key.rpartition("_")
        if edge == "start":
            open_at[(stage, who)] = int(value)
        elif edge == "minutes":
            total[stage] = total.get(stage, 0.0) + float(value)
        elif edge == "end" and (stage, who) in open_at:
            total[stage] = total.get(stage, 0.0) + (int(value) - open_at.pop((stage, who))) / 60
    return total, open_at


def merge_lines(made: Path, copy: Path) -> bytes:
    """KEPT's lines, then OUT's lines KEPT lacks (times and machines: every engine's, none lost when two
    working folders keep into one KEPT)."""
    kept = copy.read_bytes().splitlines(keepends=True) if copy.is_file() else []
    if kept and not kept[-1].endswith(b"\n"):
        kept[-1] += b"\n"
    known = set(kept)
    new = [line if line.endswith(b"\n") else line + b"\n" for line in made.read_bytes().splitlines(keepends=True)]
    return b"".join(kept + [line for line in new if line not in known and line.strip()])


def machine() -> str:
    """This machine without the process's own thread count (training threads are stated apart)."""
    text = describe_machine()
    head, _, last = text.rpartition(", ")
    return head if last.endswith("threads") else text


def machines(path: Path) -> list[str]:
    """The machines recorded in ``path``, one per line."""
    return [line for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def record_machine(layout: Layout) -> None:
    """Add this machine to OUT/machines.txt (once): it ran a stage."""
    known = machines(layout.machines)
    here = machine()
    if here not in known:
        layout.out.mkdir(parents=True, exist_ok=True)
        layout.machines.write_text("\n".join([*known, here]) + "\n")


# ------------------------------------------------------------------------------------------------ job log
def log_job(layout: Layout, job: str, event: str, **extra: Any) -> None:
    """Append one event of a job (``start`` / ``end``) with the time, host and pid to OUT/jobs.jsonl."""
    layout.out.mkdir(parents=True, exist_ok=True)
    record = {"job": job, "event": event, "time": round(time.time(), 1), "host": socket.gethostname(), **extra}
    with layout.jobs.open("a") as f:
        f.write(json.dumps(record) + "\n")


def span_minutes(events: Sequence[Mapping[str, Any]]) -> float | None:
    """Minutes of a job over every session: each ``start`` closed by the next ``end`` adds its span (a job resumed
    over three sessions counts all three; a start that no end closed, as when the machine went down, adds
    nothing). ``None`` when no span is closed."""
    total, opened = None, None
    for event in events:
        if event["event"] == "start":
            opened = event["time"]
        elif event["event"] == "end" and opened is not None:
            total = (total or 0.0) + (event["time"] - opened) / 60
            opened = None
    return total


def job_events(layout: Layout) -> dict[str, list[dict[str, Any]]]:
    """Job -> its events in OUT/jobs.jsonl (a torn last line is skipped)."""
    events: dict[str, list[dict[str, Any]]] = {}
    if layout.jobs.is_file():
        for line in layout.jobs.read_text().splitlines():
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            events.setdefault(record["job"], []).append(record)
    return events


def pid_alive(pid: int) -> bool:
    """Whether a process with this id runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def folder_holder(folder: Path) -> str | None:
    """The live abm command that holds the folder's lock (``FOLDER/.abm.lock``, :class:`abm.files.FolderLock`)
    as the lock names it (``abm train (pid 4242 on host)``), or ``None`` when none does."""
    import fcntl

    path = folder / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.read(fd, 200).decode("utf-8", "replace").strip() or "another process"
    finally:
        os.close(fd)
    return None


def folder_busy(folder: Path) -> bool:
    """Whether a live abm command holds the folder's lock (:func:`folder_holder`)."""
    return folder_holder(folder) is not None


def holder_pid(holder: str) -> str:
    """``pid N`` (and its host) out of a lock's owner text, for "already running (pid N)"."""
    found = re.search(r"pid \d+( on \S+)?", holder)
    return found.group(0) if found else holder


# ---------------------------------------------------------------------------------------------- run folders
def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """``(step, file)`` of a run folder's checkpoints, by step."""
    folder = run_dir / "checkpoints"
    found = [(int(m.group(1)), p) for p in folder.glob("step_*.pt") if (m := _STEP_FILE.match(p.name))] \
        if folder.is_dir() else []
    return sorted(found)


def last_logged_step(run_dir: Path) -> int | None:
    """The step of the last row of RUN/log.csv (``None`` before the first)."""
    log = run_dir / "log.csv"
    if not log.is_file():
        return None
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    if len(lines) < 2:
        return None
    try:
        return int(lines[-1].split(",", 1)[0])
    except ValueError:
        return None


# ---------------------------------------------------------------------------------------------------- carry
def _eval_folders(layout: Layout) -> Iterator[tuple[str, Path]]:
    root = layout.out / "eval"
    for folder in sorted(root.glob("*/*")) if root.is_dir() else []:
        if folder.is_dir():
            yield folder.relative_to(root).as_posix(), folder


DESTINATION_GROUNDING_JOB = "diagnose/destination_grounding"  #: the one diagnosis job of a spec's grounder
CARRIED = "carried.json"  #: the manifest of a carried folder: the files the carry wrote there, with their sha256


class CarryError(OutputError):
    """A carry folder holds files the carry did not write, or a carried file does not match its manifest."""


def carried_files(folder: Path) -> dict[str, str]:
    """The files the carry wrote into ``folder`` (name -> sha256), from its manifest (``{}`` without one)."""
    manifest = folder / CARRIED
    try:
        data = json.loads(manifest.read_text(encoding="utf-8")) if manifest.is_file() else {}
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise CarryError(f"{manifest} cannot be read ({err}): restore it with git checkout") from None
    files = data.get("files", {}) if isinstance(data, dict) else None
    if not isinstance(files, dict) or not all(isinstance(k, str) and "/" not in k and k not in ("", ".", "..")
                                               and isinstance(v, str) for k, v in files.items()):
        raise CarryError(f"{manifest} is not a carry manifest (files: name -> sha256): restore it with git checkout")
    return files


def clear_carried(folder: Path) -> None:
    """Remove what the carry wrote into ``folder`` (the files its manifest lists, then the manifest) and the
    folder once empty; any other file stays."""
    for name in carried_files(folder):
        (folder / name).unlink(missing_ok=True)
    (folder / CARRIED).unlink(missing_ok=True)
    try:
        folder.rmdir()
    except OSError:  # missing, or holding files the carry did not write
        pass


def _fresh_carry_folder(folder: Path) -> None:
    """Empty ``folder`` of what the carry wrote before, and refuse to write into it while it holds anything else."""
    if folder.is_symlink():
        raise CarryError(f"{folder} is a symbolic link; the carry writes only into its own folders: remove the link")
    clear_carried(folder)
    if folder.exists():
        others = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else [folder.name]
        raise CarryError(f"{folder} holds files the carry did not write ({', '.join(others[:5])}); it removes only "
                         "what it wrote: move them away, then carry again")
    folder.mkdir(parents=True)


def _seal_carry_folder(folder: Path, **about: Any) -> None:
    """Write ``folder``'s manifest: every file in it with its sha256 (and ``about``: what it carries)."""
    files = {p.name: sha256_file(p) for p in sorted(folder.iterdir()) if p.is_file() and p.name != CARRIED}
    write_text_atomic(folder / CARRIED, json.dumps({**about, "files": files}, indent=1) + "\n")


def carry_unfinished(spec: ExperimentSpec, layout: Layout) -> list[str]:
    """Copy what a continuation on another machine needs into CARRY (then commit it); returns what was copied.

    Unfinished evaluations leave their outcomes so far (``CARRY/eval/RUN/SPLIT/outcomes.jsonl``, each checkpoint
    relative to the working folder: :func:`abm.evaluation.results.portable_path`; and ``evaluation.json``);
    trainings without a zoo file yet their latest checkpoint and log (``CARRY/RUN/``): an unfinished one continues
    from it, a finished one (its export had not run) is exported from it. A finished training's checkpoint is carried
    without its training state (:func:`abm.policy.checkpoint.export_checkpoint`: about a third of the bytes; the
    optimizer's moments continue nothing), its step and records kept, so the engine sees it trained, and the sha256
    of the file it came from (``slimmed_from_sha256``), so the outcomes evaluated with that file are restored with
    it (:func:`restore_evaluation`)."""
    if layout.carry is None:
        return []
    copied = []
    for name, folder in _eval_folders(layout):
        if not (folder / "outcomes.jsonl").is_file() or (folder / "results.json").is_file():
            continue
        target = layout.carry / "eval" / name
        _fresh_carry_folder(target)
        OutcomeLog(folder / "outcomes.jsonl").copy_portable(target / "outcomes.jsonl")
        if (folder / "evaluation.json").is_file():
            shutil.copyfile(folder / "evaluation.json", target / "evaluation.json")
        _seal_carry_folder(target, carried_by=f"abm experiment run {spec.name}")
        copied.append(f"eval/{name}")
    for run in spec.runs:
        if layout.zoo is not None and layout.zoo_file(run).is_file():
            continue
        found = checkpoints(layout.run_dir(run))
        if not found:
            continue
        target = layout.carry / run
        _fresh_carry_folder(target)
        latest = found[-1][1]
        if finished_training(latest, spec.runs[run].config.steps):
            from abm.policy.checkpoint import export_checkpoint  # torch: only when a finished training is carried

            export_checkpoint(latest, target / latest.name, records={SLIMMED_FROM: sha256_file(latest)})
        else:
            shutil.copyfile(latest, target / latest.name)
        if (layout.run_dir(run) / "log.csv").is_file():
            shutil.copyfile(layout.run_dir(run) / "log.csv", target / "log.csv")
        _seal_carry_folder(target, carried_by=f"abm experiment run {spec.name}")
        copied.append(run)
    return copied


def verify_carried(folder: Path) -> dict[str, str]:
    """The files of a carried folder, each checked against the sha256 its manifest records (as a zoo file against
    its index); returns the manifest's files.

    Raises:
        CarryError: no manifest (a folder the carry did not write, or one written before carries were sealed), a
            file missing, changed, or not listed.
    """
    files = carried_files(folder)
    fix = f"restore {folder} with git checkout, or remove it to start that work again"
    if not files:
        raise CarryError(f"{folder} has no manifest ({CARRIED}) of what the carry wrote, so its files cannot be "
                         f"checked: {fix}")
    for name, digest in files.items():
        path = folder / name
        if path.is_symlink() or not path.is_file():
            raise CarryError(f"{path}, listed in {folder / CARRIED}, is missing: {fix}")
        if sha256_file(path) != digest:
            raise CarryError(f"{path} does not match the sha256 that {folder / CARRIED} records for it (a changed "
                             f"byte, a partial copy or another file): {fix}")
    extra = sorted(p.name for p in folder.iterdir() if p.name != CARRIED and p.name not in files)
    if extra:
        raise CarryError(f"{folder} holds files its manifest does not list ({', '.join(extra[:5])}): {fix}")
    return files


def checkpoint_step(path: Path) -> int | None:
    """The step a checkpoint file holds (its own record, not its file name), checked byte for byte
    (:func:`abm.policy.checkpoint.load_checkpoint`); ``None`` when it cannot be read. Read once per file
    version (path, size, modification time)."""
    return _checkpoint_record(path)[0]


def stopped_early(path: Path) -> bool:
    """Whether a checkpoint file records that its run stopped there, its curve flat (``stopped: "flat"``,
    :mod:`abm.train.early_stop`): the run is finished before its last step. Read like :func:`checkpoint_step`."""
    return _checkpoint_record(path)[1]


def finished_training(path: Path, steps: int) -> bool:
    """Whether a training's latest checkpoint holds a finished run: the last of its ``steps`` (the step it records,
    not its name), or the step where it stopped, its curve flat."""
    return (checkpoint_step(path) or 0) >= steps or stopped_early(path)


def slimmed_from(path: Path) -> str:
    """The sha256 of the checkpoint a carried checkpoint was slimmed from (``""``: none, or an unreadable file).
    Read like :func:`checkpoint_step`."""
    return _checkpoint_record(path)[2]


def _checkpoint_record(path: Path) -> tuple[int | None, bool, str]:
    try:
        stat = path.stat()
    except OSError:
        return None, False, ""
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _RECORDS:
        from abm.policy.checkpoint import load_checkpoint  # torch: only when a checkpoint is read

        try:
            ckpt = load_checkpoint(path)
        except (AbmError, OSError, ValueError, RuntimeError, EOFError):
            ckpt = {}
        step, source = ckpt.get("step"), ckpt.get(SLIMMED_FROM, "")
        _RECORDS[key] = (step if isinstance(step, int) and not isinstance(step, bool) else None,
                         ckpt.get("stopped") == "flat", source if isinstance(source, str) else "")
    return _RECORDS[key]


_RECORDS: dict[tuple[str, int, int], tuple[int | None, bool, str]] = {}

SLIMMED_FROM = "slimmed_from_sha256"
"""The record of a finished training's checkpoint carried without its training state: the sha256 of the file it
was made from, whose weights it holds (:func:`carry_unfinished`)."""


def restore_training(layout: Layout, run: str) -> bool:
    """On a fresh clone, continue a training from its carried checkpoint (when OUT has no checkpoint of it),
    once every carried file matches its manifest (:func:`verify_carried`) and the checkpoint holds the step its
    name says.

    Raises:
        CarryError: a carried file that fails those checks (nothing is copied).
    """
    if layout.carry is None:
        return False
    carried = layout.carry / run
    if not carried.is_dir() or checkpoints(layout.run_dir(run)):
        return False
    files = verify_carried(carried)
    ckpts = sorted(carried / name for name in files if _STEP_FILE.match(name))
    if not ckpts:
        return False
    for ckpt in ckpts:
        match = _STEP_FILE.match(ckpt.name)
        step = checkpoint_step(ckpt)
        if match is None or step != int(match.group(1)):
            raise CarryError(f"{ckpt} holds step {step} (its name says {int(match.group(1)) if match else '?'}): "
                             f"a renamed or foreign checkpoint; restore {carried} with git checkout, or remove it to "
                             "train from the start")
    target = layout.run_dir(run) / "checkpoints"
    target.mkdir(parents=True, exist_ok=True)
    for ckpt in ckpts:
        shutil.copyfile(ckpt, target / ckpt.name)
    if "log.csv" in files:
        shutil.copyfile(carried / "log.csv", layout.run_dir(run) / "log.csv")
    return True


def model_file(model: Path) -> Path | None:
    """The checkpoint file an evaluation of ``model`` (a zoo file or a run folder) loads."""
    if model.is_file():
        return model
    found = checkpoints(model)
    return found[-1][1] if found else None


def restore_evaluation(layout: Layout, name: str, split: str, model: Path | None = None) -> bool:
    """On a fresh clone, continue an evaluation from its carried outcomes (when OUT has none): the carried files
    must match their manifest (:func:`verify_carried`), and only the outcomes of ``model``'s bytes are restored
    (each row's ``checkpoint_sha256`` and checkpoint name): a row of another file, a changed one or one written
    before rows recorded the sha256 is refused, said in one line, and never counted (its episode runs again).

    Raises:
        CarryError: a carried file that does not match its manifest (nothing is copied).
    """
    if layout.carry is None:
        return False
    carried = layout.carry / "eval" / name / split
    folder = layout.eval_dir(name, split)
    if not carried.is_dir() or (folder / "outcomes.jsonl").exists():
        return False
    files = verify_carried(carried)
    checkpoint = model_file(model) if model is not None else None
    digest = sha256_file(checkpoint) if checkpoint is not None else ""
    same = {digest, slimmed_from(checkpoint)} - {""} if checkpoint is not None else set()
    shown = layout.show(checkpoint) if checkpoint is not None else "?"
    kept, refused = [], 0
    for line in (carried / "outcomes.jsonl").read_text().splitlines() if "outcomes.jsonl" in files else []:
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            refused += 1
            continue
        if isinstance(row, dict) and digest and row.get("checkpoint_sha256") in same and \
                row.get("checkpoint") == shown:
            kept.append(line)
        else:
            refused += 1
    if refused:
        logging.getLogger("abm").warning(
            "%s: %d of %d carried outcome(s) refused: not of %s's bytes (sha256 %s…), changed, or written before "
            "outcomes recorded it; those episodes run again", layout.show(carried), refused, refused + len(kept),
            shown, digest[:12])
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder / "outcomes.jsonl", "".join(line + "\n" for line in kept))
    for file in files:
        if file != "outcomes.jsonl":
            shutil.copyfile(carried / file, folder / file)
    return True


def drop_carry(layout: Layout, *parts: str) -> None:
    """Remove a carried state that is no longer needed (``run`` or ``eval, run``): only what the carry wrote
    (:func:`clear_carried`), so a file someone else put there stays."""
    if layout.carry is None:
        return
    folder = layout.carry.joinpath(*parts)
    if parts[:1] == ("eval",) and folder.is_dir() and not folder.is_symlink():
        for split in sorted(folder.iterdir()):  # CARRY/eval/RUN/SPLIT
            if split.is_dir() and not split.is_symlink():
                clear_carried(split)
        try:
            folder.rmdir()
        except OSError:
            pass
    elif folder.is_dir() and not folder.is_symlink():
        clear_carried(folder)
