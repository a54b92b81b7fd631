"""An evaluation as ``abm eval`` and the experiment engine's eval job (:mod:`abm.experiments.jobs`) run it
(:func:`run_evaluation` of an :class:`EvalRequest`: the tasks to roll out, the protocol written beside the outcomes,
the tables, the GIFs), and the zoo's evaluation of ``abm zoo eval`` (:func:`evaluate_zoo`). The rollouts themselves
are :mod:`abm.evaluation.runner`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import abm
from abm.configuration import WORKERS
from abm.data.episode_store import EpisodeStore
from abm.errors import ConfigError, ExternalError, OutputError
from abm.evaluation.html_report import write_html_report
from abm.evaluation.policies import checkpoint_clips
from abm.evaluation.results import (
    EpisodeOutcome,
    OutcomeLog,
    SuccessRate,
    combined_table,
    eval_seed,
    markdown_table,
    write_json,
)
from abm.evaluation.runner import (
    EvalCell,
    EvalJob,
    check_same_evaluation,
    checkpoint_of,
    crash_summary,
    evaluate,
    evaluate_together,
    method_labels,
    plan_jobs,
    run_job,
    same_file_runs,
)
from abm.evaluation.settings import (
    ZOO_EVAL_EPISODES,
    ZOO_EVAL_MAX_STEPS,
    ZOO_EVAL_SPLITS,
    ZOO_EVAL_TASKS,
    EvalSettings,
)
from abm.files import FolderLock
from abm.grounding.config import GROUNDERS
from abm.grounding.default import default_grounder
from abm.measured import reproducibility_text
from abm.policy.checkpoint import load_checkpoint
from abm.sim.splits import load_splits
from abm.sim.tasks import TASKS
from abm.zoo import COMPARED_METHODS, ZooError, edition, entry_path, named, pick, read_index, verify


@dataclass(frozen=True)
class EvalRequest:
    """One evaluation (the ``abm eval`` flags).

    Attributes:
        runs: training run folders or checkpoint files, one table row each.
        tasks: the tasks (``None``: each run's trained tasks on the splits that define objects for them).
        splits: object splits, one outcome folder each.
        episodes: episodes per task, split and repeat; ``repeats``: repeats with other scenes.
        workers: parallel rollout processes (or Ray actors, ``backend`` ``ray`` at ``ray_address``).
        gifs: GIFs of this many episodes per method and task (:func:`gif_choice`), rolled out again after.
        out: with one split its folder, with several their parent (``None``: :func:`default_eval_base`).
        settings: the options of every rollout (device, grounder, resolution, ...).
    """

    runs: Sequence[Path]
    tasks: Sequence[str] | None = None
    splits: Sequence[str] = ("seen", "unseen")
    episodes: int = 25
    repeats: int = 5
    workers: int = WORKERS
    gifs: int = 0
    out: Path | None = None
    settings: EvalSettings = field(default_factory=EvalSettings)
    backend: str = "local"
    ray_address: str | None = None


def default_tasks(split: str, splits_path: str | Path | None) -> list[str]:
    """Tasks whose objects the split file defines for ``split``."""
    splits = load_splits(splits_path)
    return [name for name in sorted(TASKS) if split in splits.tasks.get(name, {})]


def trained_tasks(runs: list[Path]) -> list[str] | None:
    """The tasks the runs were trained on (their union, in order), from each run's training config (its
    ``--tasks``, else the tasks of its episode store); ``None`` when a run's training data is unknown."""
    import json


    tasks: list[str] = []
    for run in runs:
        config = run / "config.json"
        train = (json.loads(config.read_text())["train"] if config.is_file()
                 else load_checkpoint(run).get("train_config") or {})
        names = train.get("tasks")
        if not names and train.get("data") and Path(train["data"]).is_dir():
            store = EpisodeStore(train["data"])
            names = sorted({store.episodes[i].task for i in store.select(splits=train.get("splits"))})
        if not names:
            return None
        tasks += names
    return list(dict.fromkeys(tasks))


def plan_tasks(request: EvalRequest) -> dict[str, list[str]]:
    """Split -> tasks to evaluate on it: the request's tasks on every split, else the runs' trained tasks on the
    splits that define objects for them (see :func:`trained_tasks`)."""
    splits = list(dict.fromkeys(request.splits))
    if request.tasks:
        unknown = [t for t in request.tasks if t not in TASKS]
        if unknown:
            raise TASKS.unknown(unknown[0])
        return {split: list(request.tasks) for split in splits}
    trained = trained_tasks(list(request.runs))
    plan = {}
    for split in splits:
        defined = default_tasks(split, request.settings.splits_path)
        tasks = [t for t in trained if t in defined] if trained is not None else defined
        if tasks:
            plan[split] = tasks
    source = f"trained on: {', '.join(trained)}" if trained is not None else "training data unknown: every task"
    logging.getLogger("abm").info("abm eval: tasks %s (%s; pick others with --tasks)", "; ".join(
        f"{split}: {', '.join(tasks)}" for split, tasks in plan.items()) or "none", source)
    if not plan:
        raise ConfigError(f"no task the runs were trained on ({', '.join(trained or [])}) defines objects for the "
                          f"split(s) {', '.join(splits)}; give --tasks")
    return plan


def run_evaluation(request: EvalRequest) -> None:
    """Roll the request's runs out on every task and split it names (resumable: the outcomes a folder holds are
    kept), write each split's protocol, outcomes and tables (and with several splits the combined table), print
    the table and where the files are.

    Raises:
        ConfigError: a run that does not exist, counts below 1, a task without objects in a split, nothing to
            evaluate; ExternalError: CUDA asked for and missing, or an episode that crashed (the tables are
            written first); OutputError: an output folder that is a file.
    """
    run_evaluations([request])


@dataclass
class _Prepared:
    """A checked request: its runs, tasks per split, settings, output folder per split and protocol."""

    request: EvalRequest
    plan: dict[str, list[str]]
    outs: dict[str, Path]
    parent: Path
    single: bool
    protocol: dict[str, Any]


def _prepare(request: EvalRequest) -> _Prepared:
    """Check a request (see :func:`run_evaluation`'s errors) and say where each split's outcomes go."""
    for r in request.runs:
        if not Path(r).exists():
            raise ConfigError(f"run {r} does not exist (give a training run folder or a checkpoint file)")
    if request.episodes < 1 or request.repeats < 1:
        raise ConfigError("--episodes and --repeats must be at least 1")
    runs = [Path(r) for r in same_file_runs(list(request.runs))]  # a file named twice is one run (one table row)
    request = replace(request, runs=runs)
    plan = plan_tasks(request)
    _check_setup(request, plan)
    request = replace(request, settings=_eval_grounder(request))
    settings = request.settings
    base = default_eval_base(runs[0])
    single = len(plan) == 1 and len(set(request.splits)) == 1
    parent = request.out or base
    if request.out is None:
        logging.getLogger("abm").info("abm eval: no --out: results under %s", parent)
    outs = {split: (request.out or base / f"eval_{split}") if single else parent / f"eval_{split}" for split in plan}
    for out in [*outs.values(), parent]:
        if out.exists() and not out.is_dir():
            raise OutputError(f"--out {out} is a file; give a folder")
    episodes, repeats = request.episodes, request.repeats
    rollouts = len(runs) * sum(map(len, plan.values())) * episodes * repeats
    logging.getLogger("abm").info("abm eval: %d rollouts (%d run(s) x %s x %d episodes x %d repeats)", rollouts,
                                  len(runs), " + ".join(f"{len(t)} {s} task(s)" for s, t in plan.items()),
                                  episodes, repeats)
    for split, tasks in plan.items():  # a folder of another protocol is refused before any split rolls out
        check_same_evaluation(OutcomeLog(outs[split] / "outcomes.jsonl").read(),
                              [EvalJob("", "", t, split, 0, 0, 0, settings=settings.signature()) for t in tasks],
                              outs[split], record=False)
    protocol = eval_protocol(request, plan)
    logging.getLogger("abm").info("abm eval: protocol: %d episodes x %d repeats per task and split, scene seeds %s "
                                  "(the same for every method and task), settings %s", episodes, repeats,
                                  protocol["seeds_text"], protocol["settings"])
    return _Prepared(request, plan, outs, parent, single, protocol)


def run_evaluations(requests: Sequence[EvalRequest]) -> None:
    """:func:`run_evaluation` of several requests at once (the experiment engine: each model of a split into its
    own folder), their rollouts of a scene one after another in one process, so each scene is built once for all
    (:func:`abm.evaluation.runner.evaluate_together`); the parallelism is the first request's (``workers``,
    ``backend``). Each request's folders, tables and printout are those :func:`run_evaluation` gives it alone;
    a crash in any fails the call once every table is written."""
    if not requests:
        return
    prepared = [_prepare(r) for r in requests]
    first = prepared[0].request
    cells = [(p, split, EvalCell(p.request.runs, tasks, split, p.outs[split], p.request.episodes, p.request.repeats,
                                 p.request.settings))
             for p in prepared for split, tasks in p.plan.items()]
    found_now: list[list[EpisodeOutcome]] = [[] for _ in cells]
    with ExitStack() as locks:
        for p, split, _ in cells:
            locks.enter_context(FolderLock(p.outs[split], "abm eval"))  # one writer per results folder
            (p.outs[split] / "protocol.json").write_text(json.dumps(p.protocol, indent=1) + "\n")
        found = evaluate_together([cell for _, _, cell in cells], first.workers, backend=first.backend,
                                  ray_address=first.ray_address, collect=found_now)
        for (p, split, _), now in zip(cells, found_now, strict=True):
            if p.request.gifs:
                record_gifs(list(p.request.runs), p.plan[split], split, p.outs[split], p.request.episodes,
                            p.request.gifs, p.request.settings, now)
    outcomes = [o for now in found_now for o in now]
    for p in prepared:
        rates = [r for (q, split, _), rates_of in zip(cells, found, strict=True) if q is p
                 for r in rates_of if r.split == split and r.task in p.plan[split]]
        _print_tables(p, rates)
    crashes = crash_summary(outcomes)
    if crashes:  # a crash is not a measurement: the tables are written, but the command fails
        folders = [p.outs[split] / "outcomes.jsonl" for p in prepared for split in p.plan]
        raise ExternalError(f"{crashes}; outcomes: {', '.join(str(f) for f in folders)}")


def _print_tables(p: _Prepared, rates: list[SuccessRate]) -> None:
    """Print a request's table (with several splits also written as the combined table) and where its files are."""
    if p.single:
        print(markdown_table(rates))
    else:
        table = combined_table(rates)
        repeats, episodes = p.request.repeats, p.request.episodes
        (p.parent / "eval_summary.md").write_text(
            f"Success, % ({f'mean ± std over {repeats} repeats' if repeats > 1 else 'one repeat'}; "
            f"successes / episodes); {episodes} "
            f"episodes per task, split and repeat; settings {p.request.settings.signature()}; per-split folders: "
            + ", ".join(f"[{o.name}]({o.name}/results.md)" for o in p.outs.values()) + "\n\n" + table + "\n")
        write_json(rates, p.parent / "eval_summary.json")
        print(table)
    for split, out in p.outs.items():
        print(f"results {split}: {out / 'results.md'} (also .json, .csv; per-episode outcomes in outcomes.jsonl)")
    if not p.single:
        print(f"combined table: {p.parent / 'eval_summary.md'} (also eval_summary.json)")


def default_eval_base(run: Path) -> Path:
    """Where ``abm eval`` writes without ``--out``: a training run folder's own (``RUN/eval_SPLIT``), else
    ``runs/eval/NAME`` (NAME: the checkpoint's stem or the folder's name) — never the model zoo (a folder holding
    ``index.json``, or inside one) nor the installed package."""
    folder = run if run.is_dir() else None
    if folder is not None and (folder / "config.json").is_file() and not _protected(folder):
        return folder
    return Path("runs") / "eval" / (run.stem if run.is_file() else run.resolve().name)


def _protected(folder: Path) -> bool:
    where = folder.resolve()
    package = Path(abm.__file__).resolve().parent
    return where.is_relative_to(package) or any((p / "index.json").is_file() for p in (where, *where.parents))


def eval_seeds(episodes: int, repeats: int) -> list[list[int]]:
    """The scene seeds of the protocol, one list per repeat (:func:`abm.evaluation.results.eval_seed`)."""
    return [[eval_seed(r, e) for e in range(episodes)] for r in range(repeats)]


def eval_protocol(request: EvalRequest, plan: dict[str, list[str]]) -> dict[str, Any]:
    """What an evaluation measured, written as ``protocol.json`` beside its outcomes: runs, tasks per split,
    episodes, repeats, the scene seeds and the settings, and the command that reproduces it."""
    settings = request.settings
    seeds = eval_seeds(request.episodes, request.repeats)
    runs = " ".join(f"--run {r}" for r in request.runs)
    flags = {"grounder": settings.grounder, "clip-model": settings.clip_model, "max-steps": settings.max_steps,
             "resolution": settings.resolution, "splits": settings.splits_path}
    command = (f"abm eval {runs} --split {' '.join(plan)} --episodes {request.episodes} --repeats {request.repeats}"
               + (f" --tasks {' '.join(request.tasks)}" if request.tasks else "")
               + "".join(f" --{flag} {value}" for flag, value in flags.items() if value is not None))
    ranges = [f"{row[0]}-{row[-1]}" if len(row) > 1 else str(row[0]) for row in seeds]
    return {"runs": [str(r) for r in request.runs], "tasks": plan, "episodes": request.episodes,
            "repeats": request.repeats,
            "seeds": seeds, "seeds_text": ", ".join(ranges), "settings": settings.signature(), "command": command}


def _eval_grounder(request: EvalRequest) -> EvalSettings:
    """Say which grounder the rollouts use; returns the settings they use: a grounder of a kind that uses a CLIP
    (clip, tracking) without a CLIP model, on a checkpoint that names no CLIP, takes one in the order every command
    uses (:func:`abm.grounding.default.default_grounder`)."""
    log = logging.getLogger("abm")
    settings = request.settings
    kind = settings.grounder
    if kind is None:
        log.info("abm eval: grounder: each checkpoint's own (the one it was trained with; --grounder overrides)")
        return settings
    if GROUNDERS[kind].clip and not settings.clip_model and any(not checkpoint_clips(r) for r in request.runs):
        choice = default_grounder(None, str(settings.device), clip_only=True)
        log.info("%s", choice.startup_line("eval"))
        return replace(settings, clip_model=choice.model)
    log.info("abm eval: grounder: %s%s (--grounder)", kind, f" {settings.clip_model}" if settings.clip_model else "")
    return settings


def gif_choice(outcomes: list[EpisodeOutcome], n: int) -> list[EpisodeOutcome]:
    """The episodes ``--gifs N`` shows, per method, task and split: a fixed mix chosen by rule, not by looking —
    of repeat 0's episodes in episode order, the first ceil(N/2) successes and the first floor(N/2) failures,
    topped up from the other kind when one has too few (crashed episodes are never shown)."""
    groups: dict[tuple[str, str, str], list[EpisodeOutcome]] = {}
    for o in sorted(outcomes, key=lambda o: (o.method, o.task, o.split, o.episode)):
        if o.repeat == 0 and not o.error:
            groups.setdefault((o.method, o.task, o.split), []).append(o)
    chosen = []
    for group in groups.values():
        wins = [o for o in group if o.success]
        losses = [o for o in group if not o.success]
        want_wins = min(len(wins), max((n + 1) // 2, n - len(losses)))
        picked = wins[:want_wins] + losses[:n - want_wins]
        chosen += sorted(picked, key=lambda o: o.episode)
    return chosen


def record_gifs(runs: list[Path], tasks: list[str], split: str, out: Path, episodes: int, n: int,
                settings: EvalSettings, outcomes: list[EpisodeOutcome]) -> None:
    """Roll the episodes :func:`gif_choice` picks out again with a GIF and its heatmap overlays (``out/gifs``;
    a rollout depends on the model, task, split, seed and settings alone, so it is the same episode); the ones
    already there are kept."""
    log = logging.getLogger("abm")
    chosen = {(o.method, o.task, o.episode): o for o in gif_choice(outcomes, n)}
    labels = method_labels(runs)
    checkpoints = {str(r): checkpoint_of(r) for r in runs}
    jobs = [replace(j, checkpoint=checkpoints[j.run], settings=settings.signature())
            for j in plan_jobs(runs, tasks, split, episodes, 1, out, episodes, labels)
            if (j.method, j.task, j.episode) in chosen and not Path(j.gif_path).is_file()]
    if jobs:
        log.info("abm eval: %d GIF(s) of %s, per method and task: successes and failures of repeat 0 in episode "
                 "order (--gifs %d)", len(jobs), split, n)
    for job in jobs:
        again = run_job(job, settings)
        if again.success != chosen[(job.method, job.task, job.episode)].success:
            log.warning("abm eval: the GIF of %s %s episode %d ended otherwise than its evaluated rollout",
                        job.method, job.task, job.episode)
    if jobs:  # the page written with the tables, again with the GIFs
        write_html_report(outcomes, out / "report.html", out / "gifs")


def _check_setup(request: EvalRequest, plan: dict[str, list[str]]) -> None:
    """Fail before the first rollout on what would make every episode crash."""
    import torch


    splits = load_splits(request.settings.splits_path)
    for split, tasks in plan.items():
        for task in tasks:
            defined = sorted(splits.tasks.get(task, {}))
            if split not in defined:
                raise ConfigError(f"task {task} has no objects in the {split!r} split "
                                  f"(it defines: {', '.join(defined) or 'none'})")
    device = request.settings.device
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        raise ExternalError(f"--device {device}: CUDA is not available on this machine (use --device cpu)")
    for r in request.runs:
        load_checkpoint(r)  # a missing, damaged or foreign checkpoint is refused before the first rollout


def check_zoo_clips(zoo: Path, runs: list[Path], clip: dict[str, Any] | None) -> None:
    """Refuse (:class:`ZooError`, before any rollout) a model whose CLIP does not resolve to the zoo's own
    benchmark CLIP. The models name it by the path they were trained with (``models/benchmark-clip``), which is
    looked for relative to the model's folder and its parents, then the working folder
    (:func:`abm.evaluation.policies.clip_root`)."""
    expected = entry_path(zoo, clip).resolve() if clip is not None else None
    for run in runs:
        for name, found in checkpoint_clips(run).items():
            if expected is not None and found is not None and found.resolve() == expected:
                continue
            where = f"resolves to {found}" if found is not None else "is not found"
            instead = f" instead of the zoo's {expected}" if expected is not None else ""
            raise ZooError(f"{run} names its CLIP {name!r}, which {where}{instead} (looked in {run.resolve().parent} "
                           "and its parents, then the working folder): keep the zoo's layout, the models and "
                           f"benchmark-clip/ in one folder named {Path(name).parent.name or 'models'!r} (as in the "
                           "checkout), and pass that folder as --zoo")


def edition_page(number: int) -> str:
    """The page of the paper tables' edition ``number`` (``docs/results/paper_tables.md`` for the first,
    ``docs/results/paper_tables_vN.md`` after)."""
    return "docs/results/paper_tables.md" if number == 1 else f"docs/results/paper_tables_v{number}.md"


def evaluate_zoo(zoo: Path, out: Path, tasks: Sequence[str] = ZOO_EVAL_TASKS, episodes: int = ZOO_EVAL_EPISODES,
                 workers: int = WORKERS, max_steps: int = ZOO_EVAL_MAX_STEPS, models: Sequence[str] = ()) -> None:
    """Evaluate the zoo's abm and rvt models (:data:`abm.zoo.COMPARED_METHODS`, :func:`abm.zoo.pick`; or the
    ``models`` named, :func:`abm.zoo.named`), each checked against its sha256, with the zoo's own benchmark CLIP, on
    seen and unseen objects of ``tasks``, ``episodes`` each, and write their table to ``out/results.md`` (the
    outcomes in ``out/seen``, ``out/unseen``).

    Raises:
        ZooError: no runnable model, an unknown name, a file that fails its check, or a model naming another CLIP;
        ExternalError: an episode that crashed (the table is written first).
    """
    entries = read_index(zoo)
    chosen = named(entries, models) if models else [e for e in (pick(entries, m) for m in COMPARED_METHODS) if e]
    if not chosen:
        raise ZooError(f"{zoo} holds no runnable {' or '.join(COMPARED_METHODS)} model (a CLIP-grounded one "
                       "needs the benchmark CLIP in the zoo too)")
    runs = [verify(zoo, e) for e in chosen]
    clip = next((e for e in entries if e["name"] == "benchmark-clip"), None)
    if clip is not None:
        verify(zoo, clip)
    check_zoo_clips(zoo, runs, clip)
    labels = {str(r): e["name"] for r, e in zip(runs, chosen, strict=True)}
    grounders = ", ".join(f"{e['name']}: {e.get('grounder', 'none')}" for e in chosen)
    clip_note = f" (the zoo's {entry_path(zoo, clip)}, sha256 verified)" if clip is not None else ""
    print(f"abm zoo eval: grounder: each model's own, as trained ({grounders}){clip_note}")
    settings = EvalSettings(max_steps=max_steps)
    rates = []
    outcomes: list[EpisodeOutcome] = []
    for split in ZOO_EVAL_SPLITS:
        print(f"abm zoo eval: {', '.join(labels.values())} on {split} objects of {', '.join(tasks)} "
              f"({episodes} episodes each)")
        rates += evaluate(runs, tasks, split, out / split, episodes, 1, workers, settings,
                          labels=labels, collect=outcomes)
    table = markdown_table(rates)
    (out / "results.md").write_text(table + "\n")
    print(table)
    page = edition_page(max(edition(e) for e in chosen))
    print(f"results: {out / 'results.md'}; the full tables of these models' edition: {page}")
    print(reproducibility_text())
    crashes = crash_summary(outcomes)
    if crashes:  # a crash is not a measurement: the table is written, but the command fails
        raise ExternalError(f"{crashes}; outcomes: {out / '{seen,unseen}' / 'outcomes.jsonl'}")
