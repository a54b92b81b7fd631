"""``abm eval``: roll out trained policies in ABM-Bench and print the success table."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import count, int_range


def register(subparsers: argparse._SubParsersAction) -> None:
    from abm.configuration import add_config_arguments
    from abm.evaluation.runner import EvalSettings

    p = subparsers.add_parser(
        "eval",
        help="evaluate trained policies on seeded benchmark episodes (success tables)",
        description="Roll out one or more trained policies on the same seeded scenes and write per-episode "
        "outcomes (resumable), results.json/csv and a markdown table in the paper's layout.",
    )
    p.add_argument("--run", action="append", required=True, type=Path,
                   help="training run folder or checkpoint; repeat for several methods")
    p.add_argument("--tasks", nargs="+", default=None,
                   help="tasks to evaluate (default: every task the split defines objects for)")
    p.add_argument("--split", default="unseen", choices=("seen", "unseen", "compositional"))
    p.add_argument("--episodes", type=int_range(1, 10**6), default=25, help="episodes per task and repeat (paper: 25)")
    p.add_argument("--repeats", type=int_range(1, 1000), default=5, help="repeats with different scenes (paper: 5)")
    p.add_argument("--workers", type=int_range(1, 256), default=1, help="parallel rollout processes")
    add_config_arguments(p, EvalSettings)  # --device, --grounder, --resolution, --max-steps, --splits
    p.add_argument("--gifs", type=count, default=0, help="save front-camera GIFs of this many episodes per task")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: FIRST_RUN/eval_SPLIT)")
    p.set_defaults(func=run)


def default_tasks(split: str, splits_path: Path | None) -> list[str]:
    """Tasks whose objects the split file defines for ``split``."""
    from abm.sim.splits import load_splits
    from abm.sim.tasks import TASKS

    splits = load_splits(splits_path)
    return [name for name in sorted(TASKS) if split in splits.tasks.get(name, {})]


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.configuration import config_from_args
    from abm.evaluation.results import markdown_table
    from abm.evaluation.runner import EvalSettings, evaluate
    from abm.files import FolderLock
    from abm.sim.tasks import TASKS

    for r in args.run:
        if not r.exists():
            raise CommandError(f"run {r} does not exist (give a training run folder or a checkpoint file)")
    if args.episodes < 1 or args.repeats < 1:
        raise CommandError("--episodes and --repeats must be at least 1")
    tasks = args.tasks or default_tasks(args.split, args.splits_path)
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        raise CommandError(f"unknown tasks {unknown}; known tasks: {sorted(TASKS)}")
    if not tasks:
        raise CommandError(f"no task defines objects for the {args.split!r} split")
    _check_setup(args, tasks)
    out = args.out or (args.run[0] if args.run[0].is_dir() else args.run[0].parent) / f"eval_{args.split}"
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out} is a file; give a folder")
    settings = config_from_args(EvalSettings, args)
    with FolderLock(out, "abm eval"):  # one writer per results folder
        rates = evaluate(args.run, tasks, args.split, out, args.episodes, args.repeats, args.workers, settings,
                         gifs=args.gifs)
    print(markdown_table([r for r in rates if r.split == args.split and r.task in tasks]))
    errors = sum(r.errors for r in rates)
    print(f"results: {out / 'results.md'} (also .json, .csv; per-episode outcomes in outcomes.jsonl)")
    if errors:
        print(f"{errors} episode(s) crashed and count as failures; see {out / 'outcomes.jsonl'}")
        if errors == sum(r.episodes for r in rates):
            from abm.evaluation.results import OutcomeLog

            latest = [o.error for o in OutcomeLog(out / "outcomes.jsonl").read() if o.error][-1:]  # this run's
            raise CommandError(f"every episode crashed, so the table measures nothing; last error: "
                               f"{latest[0] if latest else '?'}")
    return 0


def _check_setup(args: argparse.Namespace, tasks: list[str]) -> None:
    """Fail before the first rollout on what would make every episode crash."""
    import torch

    from abm.cli import CommandError
    from abm.policy.checkpoint import load_checkpoint
    from abm.sim.splits import load_splits

    splits = load_splits(args.splits_path)
    for task in tasks:
        defined = sorted(splits.tasks.get(task, {}))
        if args.split not in defined:
            raise CommandError(f"task {task} has no objects in the {args.split!r} split "
                               f"(it defines: {', '.join(defined) or 'none'})")
    if str(args.device).startswith("cuda") and not torch.cuda.is_available():
        raise CommandError(f"--device {args.device}: CUDA is not available on this machine (use --device cpu)")
    for r in args.run:
        try:
            load_checkpoint(r)
        except (ValueError, FileNotFoundError) as err:
            raise CommandError(str(err)) from err
