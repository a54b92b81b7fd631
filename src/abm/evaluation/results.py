"""Evaluation records, their resumable on-disk log, and the success tables.

One :class:`EpisodeOutcome` per rollout is appended to a JSON-lines log as soon as the rollout ends,
so an interrupted evaluation loses at most the episode in flight and a re-run skips finished ones.
Success rates follow the paper's protocol: per repeat, the percentage of successful episodes; per
(method, task, split), the mean and standard deviation of that percentage over the repeats.
"""

from __future__ import annotations

import csv
import hashlib
import json
import lzma
import math
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from abm.files import atomic_path, sha256_file, write_text_atomic

# Evaluation seeds live far from the data-generation seeds (which start at 0), so evaluation scenes
# are never training scenes. Episode e of repeat r uses EVAL_SEED_BASE + r * SEEDS_PER_REPEAT + e.
EVAL_SEED_BASE = 1_000_000
SEEDS_PER_REPEAT = 10_000


def eval_seed(repeat: int, episode: int) -> int:
    """The scene seed of one evaluation episode: the same for every method, task-independent."""
    if not 0 <= episode < SEEDS_PER_REPEAT:
        raise ValueError(f"episode index must be in [0, {SEEDS_PER_REPEAT}), got {episode}")
    return EVAL_SEED_BASE + repeat * SEEDS_PER_REPEAT + episode


@dataclass
class EpisodeOutcome:
    """The result of one evaluation rollout.

    Attributes:
        method: the policy's variant name (``abm``, ``rvt``, ...) or a label for the run.
        task, split: what was evaluated.
        repeat, episode: indices within the protocol; ``seed`` is the scene seed used.
        success: whether the task's success predicate held before the step limit.
        steps: keyframes the policy predicted.
        seconds: wall-clock time of the rollout.
        error: the exception text when the rollout crashed (counted as a failure), else ``""``.
        checkpoint: the checkpoint file that was evaluated; the log records it relative to the working folder when
            it lies inside it (:func:`portable_path`), so a log carried to another clone names the same file.
        settings: the evaluation settings (grounder, resolution, step limit, ...) as compact JSON.
        failure: why a failed rollout failed (:func:`failure_reason`; ``""`` on success or in older logs).
        subgoals: whether each sub-goal was reached, for two-target instructions (``[grasped X, X placed in
            Y]``, :func:`subgoal_results`); empty for one-target instructions and in older logs.
        instruction: the episode's instruction; ``target``: the object(s) it names, comma-separated (``""`` in
            older logs, or when the scene could not be built).
        trajectory: digest of the keyframes the policy predicted (:func:`trajectory_digest`), so two commands'
            outcomes can be compared beyond success (``""`` in older logs and for crashed rollouts).
        code: digest of the abm source that rolled the episode out (:func:`abm.evaluation.policies.code_digest`;
            ``""`` in older logs): outcomes of two commands are only comparable when it matches.
        grounding: per step of a mask policy, the target decision ``abm run`` would have taken on the grounder's
            answer (:func:`abm.grounding.decision.decide_target`: ``found``, ``confidence``, ``target``,
            ``reason``); evaluation logs it and acts anyway. Empty for variants without a mask and in older logs.
        step_records: one compact JSON record per executed keyframe (:class:`abm.evaluation.step_records.StepRecord`:
            the keyframe predicted, the motion's status, the held state, the nearest expert keyframe, the grounding
            decision), which :func:`abm.evaluation.step_records.episode_failure` names the failure from; empty in
            older logs and for crashed rollouts. Extra data: the trajectory digest does not cover it.
        checkpoint_sha256: the sha256 of the checkpoint file's bytes (:func:`checkpoint_sha256`, filled in by
            :meth:`OutcomeLog.append`), which binds the outcome to the model it measured (an experiment's carry
            refuses rows of another file); ``""`` in older logs.
    """

    method: str
    task: str
    split: str
    repeat: int
    episode: int
    seed: int
    success: bool
    steps: int = 0
    seconds: float = 0.0
    error: str = ""
    checkpoint: str = ""
    settings: str = ""
    failure: str = ""
    subgoals: list[bool] = field(default_factory=list)
    instruction: str = ""
    target: str = ""
    trajectory: str = ""
    code: str = ""
    grounding: list[dict[str, Any]] = field(default_factory=list)
    step_records: list[dict[str, Any]] = field(default_factory=list)
    checkpoint_sha256: str = ""

    @property
    def key(self) -> RolloutKey:
        """Identity of the rollout (:func:`rollout_key`)."""
        return rollout_key(self)


RolloutKey = tuple[str, str, str, int, int, str, str]


def rollout_key(rollout: Any) -> RolloutKey:
    """Identity of one rollout, shared by an :class:`EpisodeOutcome` and the job that produces it: its protocol
    position (method, task, split, repeat, episode), the checkpoint as :func:`portable_path` names it and the
    evaluation settings used."""
    return (rollout.method, rollout.task, rollout.split, rollout.repeat, rollout.episode,
            portable_path(rollout.checkpoint), rollout.settings)


def portable_path(path: str) -> str:
    """``path`` relative to the working folder (POSIX separators) when it is absolute and lies inside it, else
    ``path`` unchanged: how an outcome log names a checkpoint, so the log of ``/a/clone/models/m.pt`` and of
    ``/b/clone/models/m.pt`` agree (``models/m.pt``) when each is run from its clone's root."""
    if not path or not Path(path).is_absolute():
        return path
    try:
        return Path(path).relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path


def trajectory_digest(actions: Iterable[Any]) -> str:
    """16 hex digits of SHA-1 over the keyframe actions (position, quaternion, gripper, collision flag), in order."""
    h = hashlib.sha1()
    for a in actions:
        h.update(np.concatenate([np.asarray(a.position, np.float64), np.asarray(a.quaternion, np.float64),
                                 [float(a.gripper_open), float(a.ignore_collision)]]).tobytes())
    return h.hexdigest()[:16]


FAILURES = ("crashed", "IK unreachable", "motion blocked", "collision", "grasp missed", "timeout")


def failure_reason(success: bool, error: str, motions: Sequence[str], held_target: bool) -> str:
    """Why a rollout failed, in :data:`FAILURES` order of precedence (``""`` when it succeeded), from the motion
    statuses alone: the rule of logs written before per-step records existed. ``abm eval`` now names the first
    stop the policy did not recover from (:func:`abm.evaluation.step_records.episode_failure`).

    ``crashed``: the rollout raised; ``IK unreachable``: a keyframe pose had no IK solution (the arm did not
    move); ``motion blocked``: the arm moved but stopped short of a keyframe pose (e.g. pressing into an
    object); ``collision``: the arm touched the scene on a transfer; ``grasp missed``: the gripper never
    held the target; ``timeout``: it held it but the task was not done within the step limit (e.g. placed
    wrong). Logs written before ``blocked`` existed count blocked motions as ``IK unreachable``.
    """
    if success:
        return ""
    if error:
        return "crashed"
    if "unreachable" in motions:
        return "IK unreachable"
    if "blocked" in motions:
        return "motion blocked"
    if "collided" in motions:
        return "collision"
    return "timeout" if held_target else "grasp missed"


class OutcomeLog:
    """Append-only JSON-lines file of :class:`EpisodeOutcome` records (one per line).

    A truncated last line (the process was killed while writing) is ignored on reading.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def read(self) -> list[EpisodeOutcome]:
        if not self.path.exists():
            return []
        return parse_outcomes(self.path.read_text())

    def copy_portable(self, target: str | Path) -> None:
        """Write this log's outcomes to ``target`` with every checkpoint as :func:`portable_path` names it (what an
        experiment's carry commits: older logs named absolute paths)."""
        write_text_atomic(target, "".join(json.dumps(portable_record(o)) + "\n" for o in self.read()))

    def done(self) -> set[tuple[str, str, str, int, int, str, str]]:
        """Keys of the episodes already recorded without an error (crashed ones are run again)."""
        return {o.key for o in self.read() if not o.error}

    def append(self, outcome: EpisodeOutcome) -> None:
        """Append one outcome (with its checkpoint's sha256, :func:`checkpoint_sha256`)."""
        if outcome.checkpoint and not outcome.checkpoint_sha256:
            outcome = replace(outcome, checkpoint_sha256=checkpoint_sha256(outcome.checkpoint))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a+b") as f:
            f.seek(0, 2)
            torn = f.tell() > 0 and (f.seek(-1, 2), f.read(1))[1] != b"\n"
            # after an interrupted write, start a new line so this record is not glued to the torn one
            f.write((b"\n" if torn else b"") + (json.dumps(portable_record(outcome)) + "\n").encode())
            f.flush()


_DIGESTS: dict[tuple[str, int, int], str] = {}


def checkpoint_sha256(path: str | Path) -> str:
    """The sha256 of a checkpoint file's bytes (computed once per file version: path, size, modification time);
    ``""`` when it is no file."""
    try:
        stat = Path(path).stat()
    except OSError:
        return ""
    key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _DIGESTS and Path(path).is_file():
        _DIGESTS[key] = sha256_file(path)
    return _DIGESTS.get(key, "")


def portable_record(outcome: EpisodeOutcome) -> dict[str, Any]:
    """The JSON record of one outcome as the log writes it (its checkpoint through :func:`portable_path`)."""
    return {**asdict(outcome), "checkpoint": portable_path(outcome.checkpoint)}


def parse_outcomes(text: str) -> list[EpisodeOutcome]:
    """The outcomes of JSON-lines ``text``; unparsable lines (a write cut short) are skipped, and keys of newer
    logs this version does not know are left out."""
    names = {f.name for f in fields(EpisodeOutcome)}
    outcomes = []
    for line in text.splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # a partial line from an interrupted write
        outcomes.append(EpisodeOutcome(**{k: v for k, v in record.items() if k in names}))
    return outcomes


OUTCOME_ARCHIVE = "outcomes.jsonl.xz"
"""File name of the compressed per-episode outcomes an evaluation writes beside its tables
(:func:`write_outcome_archive`)."""


def write_outcome_archive(outcomes: Iterable[EpisodeOutcome], path: str | Path) -> Path:
    """Write ``outcomes`` (with their per-step records) as xz-compressed JSON lines, in protocol order (method,
    task, split, repeat, episode), each checkpoint as :func:`portable_path` names it: the file an experiment
    commits beside its summaries so any failure can be traced without rolling it out again. The same outcomes
    give the same bytes (the file is only rewritten in a commit when an outcome changed)."""
    ordered = sorted(outcomes, key=lambda o: (o.method, o.task, o.split, o.repeat, o.episode))
    text = "".join(json.dumps(portable_record(o), separators=(",", ":")) + "\n" for o in ordered)
    with atomic_path(path) as tmp:
        tmp.write_bytes(lzma.compress(text.encode(), preset=9))
    return Path(path)


def read_outcome_archive(path: str | Path) -> list[EpisodeOutcome]:
    """The outcomes of a file :func:`write_outcome_archive` wrote."""
    return parse_outcomes(lzma.decompress(Path(path).read_bytes()).decode())


@dataclass
class SuccessRate:
    """Success of one (method, task, split): percentages per repeat and their mean and std, the successful
    episodes out of ``episodes``, and the failed ones by reason (``failures``: :data:`FAILURES`, ``unknown``
    for logs written before reasons were recorded)."""

    method: str
    task: str
    split: str
    per_repeat: list[float]
    episodes: int
    errors: int
    successes: int = 0
    failures: dict[str, int] = field(default_factory=dict)

    @property
    def mean(self) -> float:
        return sum(self.per_repeat) / len(self.per_repeat)

    @property
    def std(self) -> float:
        """Population standard deviation over repeats (0 for a single repeat)."""
        m = self.mean
        return math.sqrt(sum((x - m) ** 2 for x in self.per_repeat) / len(self.per_repeat))


def subgoal_results(roles: int, held_target: bool, success: bool) -> list[bool]:
    """Per-sub-goal success of a rollout: ``[]`` for one-target instructions; for two-target ones
    ``[the gripper held X at some point, the task succeeded]`` (placing X in Y is the task's predicate)."""
    return [] if roles < 2 else [bool(held_target or success), bool(success)]


def subgoal_rates(outcomes: Iterable[EpisodeOutcome]) -> list[tuple[str, str, str, list[float], int]]:
    """``(method, task, split, [% reaching each sub-goal], episodes)`` for groups with two-target rollouts."""
    groups: dict[tuple[str, str, str], list[list[bool]]] = defaultdict(list)
    for o in outcomes:
        if o.subgoals:
            groups[(o.method, o.task, o.split)].append(list(o.subgoals))
    rows = []
    for key, results in sorted(groups.items()):
        n = max(len(r) for r in results)
        rates = [100.0 * sum(r[i] for r in results if len(r) > i) / len(results) for i in range(n)]
        rows.append((*key, rates, len(results)))
    return rows


def _failure_order(reason: str) -> tuple[int, str]:
    return (FAILURES.index(reason) if reason in FAILURES else len(FAILURES), reason)


def aggregate(outcomes: Iterable[EpisodeOutcome]) -> list[SuccessRate]:
    """Group outcomes by (method, task, split) and compute the per-repeat success percentages."""
    groups: dict[tuple[str, str, str], dict[int, list[EpisodeOutcome]]] = defaultdict(lambda: defaultdict(list))
    for o in outcomes:
        groups[(o.method, o.task, o.split)][o.repeat].append(o)
    rates = []
    for (method, task, split), repeats in sorted(groups.items()):
        per_repeat = [100.0 * sum(o.success for o in eps) / len(eps) for _, eps in sorted(repeats.items())]
        all_eps = [o for eps in repeats.values() for o in eps]
        failures = Counter(o.failure or "unknown" for o in all_eps if not o.success)
        rates.append(SuccessRate(method, task, split, per_repeat, len(all_eps), sum(bool(o.error) for o in all_eps),
                                 sum(bool(o.success) for o in all_eps),
                                 {k: failures[k] for k in sorted(failures, key=_failure_order)}))
    return rates


def write_csv(rates: Sequence[SuccessRate], path: str | Path) -> None:
    """One row per (method, task, split) with mean, std, repeats, episodes and crashed episodes."""
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["method", "task", "split", "mean", "std", "repeats", "episodes", "errors"])
        for r in rates:
            writer.writerow([r.method, r.task, r.split, f"{r.mean:.2f}", f"{r.std:.2f}", len(r.per_repeat),
                             r.episodes, r.errors])


def write_json(rates: Sequence[SuccessRate], path: str | Path) -> None:
    payload = [dict(asdict(r), mean=r.mean, std=r.std) for r in rates]
    write_text_atomic(path, json.dumps(payload, indent=2) + "\n")


def rate_cell(rate: SuccessRate | None, digits: int = 1) -> str:
    """``mean ± std (successes/episodes)`` in percent; without ``± std`` for a single repeat; ``–`` for none."""
    if rate is None:
        return "–"
    std = f" ± {rate.std:.{digits}f}" if len(rate.per_repeat) > 1 else ""
    return f"{rate.mean:.{digits}f}{std} ({rate.successes}/{rate.episodes})"


def markdown_table(rates: Sequence[SuccessRate], splits: Sequence[str] | None = None) -> str:
    """The paper's Table 1 layout: one block per split, methods as rows, tasks as columns, plus the mean.

    Cells read ``mean ± std (successes/episodes)`` success in percent (:func:`rate_cell`); the "avg" column
    averages the task means.
    """
    splits = list(splits) if splits is not None else sorted({r.split for r in rates})
    lines = []
    for split in splits:
        block = [r for r in rates if r.split == split]
        if not block:
            continue
        tasks = sorted({r.task for r in block})
        methods = list(dict.fromkeys(r.method for r in block))
        cell = {(r.method, r.task): r for r in block}
        lines.append(f"**{split}**\n")
        lines.append("| method | " + " | ".join(tasks) + " | avg |")
        lines.append("|---|" + "---|" * (len(tasks) + 1))
        for m in methods:
            row = [cell.get((m, t)) for t in tasks]
            means = [r.mean for r in row if r is not None]
            cells = [rate_cell(r) for r in row]
            avg = f"{sum(means) / len(means):.1f}" if means else "–"
            lines.append(f"| {m} | " + " | ".join(cells) + f" | {avg} |")
        lines.append("")
    return "\n".join(lines)


def split_averages(rates: Sequence[SuccessRate], method: str) -> dict[str, float]:
    """Split -> mean over tasks of ``method``'s success (%), for the splits it was evaluated on."""
    by_split: dict[str, list[float]] = defaultdict(list)
    for r in rates:
        if r.method == method:
            by_split[r.split].append(r.mean)
    return {split: sum(means) / len(means) for split, means in by_split.items()}


def combined_table(rates: Sequence[SuccessRate], digits: int = 1) -> str:
    """One table over every split: a row per method, a column per (task, split) (:func:`rate_cell`), then
    the average over tasks of each split and, with both, unseen avg / seen avg (the README's layout)."""
    order = ["seen", "unseen", "compositional"]
    splits = sorted({r.split for r in rates}, key=lambda s: (order.index(s) if s in order else len(order), s))
    tasks = sorted({r.task for r in rates})
    columns = [(t, s) for s in splits for t in tasks if any(r.task == t and r.split == s for r in rates)]
    cell = {(r.method, r.task, r.split): r for r in rates}
    ratio = "seen" in splits and "unseen" in splits
    head = ["method", *(f"{t} {s}" for t, s in columns), *(f"{s} avg" for s in splits)]
    head += ["unseen / seen"] if ratio else []
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for method in dict.fromkeys(r.method for r in rates):
        avgs = split_averages(rates, method)
        row = [method, *(rate_cell(cell.get((method, t, s)), digits) for t, s in columns)]
        row += [f"{avgs[s]:.{digits}f}" if s in avgs else "–" for s in splits]
        if ratio:
            seen, unseen = avgs.get("seen", 0.0), avgs.get("unseen")
            row.append(f"{unseen / seen:.2f}" if seen > 0 and unseen is not None else "–")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)
