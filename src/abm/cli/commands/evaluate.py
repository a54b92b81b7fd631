"""``abm eval``: roll out trained policies in ABM-Bench and print the success table."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli import CommandError
from abm.configuration import config_from_args
from abm.data.episode_store import EpisodeStore
from abm.evaluation.results import EpisodeOutcome, OutcomeLog, combined_table, markdown_table, write_json
from abm.evaluation.runner import (
    EvalJob,
    EvalSettings,
    check_same_evaluation,
    crash_summary,
    evaluate,
    same_file_runs,
)
from abm.files import FolderLock
from abm.policy.checkpoint import load_checkpoint
from abm.ray_pool import RayBackendError
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
    import logging


    splits = list(dict.fromkeys(args.split))
    if args.tasks:
        unknown = [t for t in args.tasks if t not in TASKS]
        if unknown:
            raise CommandError(f"unknown tasks {unknown}; known tasks: {sorted(TASKS)}")
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
        raise CommandError(f"no task the runs were trained on ({', '.join(trained or [])}) defines objects for the "
                           f"split(s) {', '.join(splits)}; give --tasks")
    return plan


def run(args: argparse.Namespace) -> int:
    import logging


    for r in args.run:
        if not r.exists():
            raise CommandError(f"run {r} does not exist (give a training run folder or a checkpoint file)")
    if args.episodes < 1 or args.repeats < 1:
        raise CommandError("--episodes and --repeats must be at least 1")
    args.run = [Path(r) for r in same_file_runs(args.run)]  # a file named twice is one run (one table row)
    plan = plan_tasks(args)
    _check_setup(args, plan)
    base = args.run[0] if args.run[0].is_dir() else args.run[0].parent
    single = len(plan) == 1 and len(set(args.split)) == 1
    parent = args.out or base
    outs = {split: (args.out or base / f"eval_{split}") if single else parent / f"eval_{split}" for split in plan}
    for out in [*outs.values(), parent]:
        if out.exists() and not out.is_dir():
            raise CommandError(f"--out {out} is a file; give a folder")
    settings = config_from_args(EvalSettings, args)
    rollouts = len(args.run) * sum(map(len, plan.values())) * args.episodes * args.repeats
    logging.getLogger("abm").info("abm eval: %d rollouts (%d run(s) x %s x %d episodes x %d repeats)", rollouts,
                                  len(args.run), " + ".join(f"{len(t)} {s} task(s)" for s, t in plan.items()),
                                  args.episodes, args.repeats)
    for split, tasks in plan.items():  # a folder of another protocol is refused before any split rolls out
        check_same_evaluation(OutcomeLog(outs[split] / "outcomes.jsonl").read(),
                              [EvalJob("", "", t, split, 0, 0, 0, settings=settings.signature()) for t in tasks],
                              outs[split], record=False)
    rates = []
    outcomes: list[EpisodeOutcome] = []
    for split, tasks in plan.items():
        try:
            with FolderLock(outs[split], "abm eval"):  # one writer per results folder
                found = evaluate(args.run, tasks, split, outs[split], args.episodes, args.repeats, args.workers,
                                 settings, gifs=args.gifs, backend=args.backend, ray_address=args.ray_address,
                                 collect=outcomes)
        except RayBackendError as err:
            raise CommandError(str(err)) from None
        rates += [r for r in found if r.split == split and r.task in tasks]
    if single:
        print(markdown_table(rates))
    else:
        table = combined_table(rates)
        (parent / "eval_summary.md").write_text(
            f"Success, % (mean ± std over {args.repeats} repeats; successes / episodes); {args.episodes} "
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
        raise CommandError(f"{crashes}; outcomes: {', '.join(str(o / 'outcomes.jsonl') for o in outs.values())}")
    return 0


def _check_setup(args: argparse.Namespace, plan: dict[str, list[str]]) -> None:
    """Fail before the first rollout on what would make every episode crash."""
    import torch


    splits = load_splits(args.splits_path)
    for split, tasks in plan.items():
        for task in tasks:
            defined = sorted(splits.tasks.get(task, {}))
            if split not in defined:
                raise CommandError(f"task {task} has no objects in the {split!r} split "
                                   f"(it defines: {', '.join(defined) or 'none'})")
    if str(args.device).startswith("cuda") and not torch.cuda.is_available():
        raise CommandError(f"--device {args.device}: CUDA is not available on this machine (use --device cpu)")
    for r in args.run:
        try:
            load_checkpoint(r)
        except (ValueError, FileNotFoundError) as err:
            raise CommandError(str(err)) from err
