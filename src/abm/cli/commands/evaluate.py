"""``abm eval``: roll out trained policies in ABM-Bench and print the success table."""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import abm
from abm.configuration import config_from_args
from abm.data.episode_store import EpisodeStore
from abm.errors import ConfigError, ExternalError, OutputError
from abm.evaluation.html_report import write_html_report
from abm.evaluation.policies import checkpoint_clips
from abm.evaluation.results import (
    EpisodeOutcome,
    OutcomeLog,
    combined_table,
    eval_seed,
    markdown_table,
    write_json,
)
from abm.evaluation.runner import (
    EvalJob,
    check_same_evaluation,
    checkpoint_of,
    crash_summary,
    evaluate,
    method_labels,
    plan_jobs,
    run_job,
    same_file_runs,
)
from abm.evaluation.settings import EvalSettings
from abm.files import FolderLock
from abm.grounding.config import GROUNDERS
from abm.grounding.default import default_grounder
from abm.policy.checkpoint import load_checkpoint
from abm.sim.splits import load_splits
from abm.sim.tasks import TASKS


def default_tasks(split: str, splits_path: Path | None) -> list[str]:
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


def plan_tasks(args: argparse.Namespace) -> dict[str, list[str]]:
    """Split -> tasks to evaluate on it: ``--tasks`` on every split, else the runs' trained tasks on the splits
    that define objects for them (see :func:`trained_tasks`)."""
    splits = list(dict.fromkeys(args.split))
    if args.tasks:
        unknown = [t for t in args.tasks if t not in TASKS]
        if unknown:
            raise TASKS.unknown(unknown[0])
        return {split: list(args.tasks) for split in splits}
    trained = trained_tasks(args.run)
    plan = {}
    for split in splits:
        defined = default_tasks(split, args.splits_path)
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


def run(args: argparse.Namespace) -> int:
    for r in args.run:
        if not r.exists():
            raise ConfigError(f"run {r} does not exist (give a training run folder or a checkpoint file)")
    if args.episodes < 1 or args.repeats < 1:
        raise ConfigError("--episodes and --repeats must be at least 1")
    args.run = [Path(r) for r in same_file_runs(args.run)]  # a file named twice is one run (one table row)
    plan = plan_tasks(args)
    _check_setup(args, plan)
    _eval_grounder(args)
    base = default_eval_base(args.run[0])
    single = len(plan) == 1 and len(set(args.split)) == 1
    parent = args.out or base
    if args.out is None:
        logging.getLogger("abm").info("abm eval: no --out: results under %s", parent)
    outs = {split: (args.out or base / f"eval_{split}") if single else parent / f"eval_{split}" for split in plan}
    for out in [*outs.values(), parent]:
        if out.exists() and not out.is_dir():
            raise OutputError(f"--out {out} is a file; give a folder")
    settings = config_from_args(EvalSettings, args)
    rollouts = len(args.run) * sum(map(len, plan.values())) * args.episodes * args.repeats
    logging.getLogger("abm").info("abm eval: %d rollouts (%d run(s) x %s x %d episodes x %d repeats)", rollouts,
                                  len(args.run), " + ".join(f"{len(t)} {s} task(s)" for s, t in plan.items()),
                                  args.episodes, args.repeats)
    for split, tasks in plan.items():  # a folder of another protocol is refused before any split rolls out
        check_same_evaluation(OutcomeLog(outs[split] / "outcomes.jsonl").read(),
                              [EvalJob("", "", t, split, 0, 0, 0, settings=settings.signature()) for t in tasks],
                              outs[split], record=False)
    protocol = eval_protocol(args, plan, settings)
    logging.getLogger("abm").info("abm eval: protocol: %d episodes x %d repeats per task and split, scene seeds %s "
                                  "(the same for every method and task), settings %s", args.episodes, args.repeats,
                                  protocol["seeds_text"], protocol["settings"])
    rates = []
    outcomes: list[EpisodeOutcome] = []
    for split, tasks in plan.items():
        with FolderLock(outs[split], "abm eval"):  # one writer per results folder
            (outs[split] / "protocol.json").write_text(json.dumps(protocol, indent=1) + "\n")
            found_now: list[EpisodeOutcome] = []
            found = evaluate(args.run, tasks, split, outs[split], args.episodes, args.repeats, args.workers,
                             settings, backend=args.backend, ray_address=args.ray_address, collect=found_now)
            outcomes += found_now
            if args.gifs:
                record_gifs(args.run, tasks, split, outs[split], args.episodes, args.gifs, settings, found_now)
        rates += [r for r in found if r.split == split and r.task in tasks]
    if single:
        print(markdown_table(rates))
    else:
        table = combined_table(rates)
        (parent / "eval_summary.md").write_text(
            f"Success, % ({f'mean ± std over {args.repeats} repeats' if args.repeats > 1 else 'one repeat'}; "
            f"successes / episodes); {args.episodes} "
            f"episodes per task, split and repeat; settings {settings.signature()}; per-split folders: "
            + ", ".join(f"[{o.name}]({o.name}/results.md)" for o in outs.values()) + "\n\n" + table + "\n")
        write_json(rates, parent / "eval_summary.json")
        print(table)
    for split, out in outs.items():
        print(f"results {split}: {out / 'results.md'} (also .json, .csv; per-episode outcomes in outcomes.jsonl)")
    if not single:
        print(f"combined table: {parent / 'eval_summary.md'} (also eval_summary.json)")
    crashes = crash_summary(outcomes)
    if crashes:  # a crash is not a measurement: the tables are written, but the command fails
        raise ExternalError(f"{crashes}; outcomes: {', '.join(str(o / 'outcomes.jsonl') for o in outs.values())}")
    return 0


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


def eval_protocol(args: argparse.Namespace, plan: dict[str, list[str]], settings: EvalSettings) -> dict[str, Any]:
    """What an evaluation measured, written as ``protocol.json`` beside its outcomes: runs, tasks per split,
    episodes, repeats, the scene seeds and the settings, and the command that reproduces it."""
    seeds = eval_seeds(args.episodes, args.repeats)
    runs = " ".join(f"--run {r}" for r in args.run)
    flags = {"grounder": settings.grounder, "clip-model": settings.clip_model, "max-steps": settings.max_steps,
             "resolution": settings.resolution, "splits": settings.splits_path}
    command = (f"abm eval {runs} --split {' '.join(plan)} --episodes {args.episodes} --repeats {args.repeats}"
               + (f" --tasks {' '.join(args.tasks)}" if args.tasks else "")
               + "".join(f" --{flag} {value}" for flag, value in flags.items() if value is not None))
    ranges = [f"{row[0]}-{row[-1]}" if len(row) > 1 else str(row[0]) for row in seeds]
    return {"runs": [str(r) for r in args.run], "tasks": plan, "episodes": args.episodes, "repeats": args.repeats,
            "seeds": seeds, "seeds_text": ", ".join(ranges), "settings": settings.signature(), "command": command}


def _eval_grounder(args: argparse.Namespace) -> None:
    """Say which grounder the rollouts use; ``--grounder`` of a kind that uses a CLIP (clip, tracking) without
    ``--clip-model`` on a checkpoint that names no CLIP takes one in the order every command uses
    (:func:`abm.grounding.default.default_grounder`)."""
    log = logging.getLogger("abm")
    kind = getattr(args, "grounder", None)
    if kind is None:
        log.info("abm eval: grounder: each checkpoint's own (the one it was trained with; --grounder overrides)")
        return
    if GROUNDERS[kind].clip and not args.clip_model and any(not checkpoint_clips(r) for r in args.run):
        choice = default_grounder(None, str(args.device), clip_only=True)
        args.clip_model = choice.model
        log.info("%s", choice.startup_line("eval"))
        return
    log.info("abm eval: grounder: %s%s (--grounder)", kind, f" {args.clip_model}" if args.clip_model else "")


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


def _check_setup(args: argparse.Namespace, plan: dict[str, list[str]]) -> None:
    """Fail before the first rollout on what would make every episode crash."""
    import torch


    splits = load_splits(args.splits_path)
    for split, tasks in plan.items():
        for task in tasks:
            defined = sorted(splits.tasks.get(task, {}))
            if split not in defined:
                raise ConfigError(f"task {task} has no objects in the {split!r} split "
                                  f"(it defines: {', '.join(defined) or 'none'})")
    if str(args.device).startswith("cuda") and not torch.cuda.is_available():
        raise ExternalError(f"--device {args.device}: CUDA is not available on this machine (use --device cpu)")
    for r in args.run:
        load_checkpoint(r)  # a missing, damaged or foreign checkpoint is refused before the first rollout
