"""``abm eval``: roll out trained policies in ABM-Bench and print the success table."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import SPLITS, WORKERS, add_config_arguments, count, int_range
from abm.evaluation.settings import EvalSettings
from abm.ray_pool import add_backend_arguments


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "eval",
        help="evaluate trained policies on seeded benchmark episodes (success tables)",
        description="Roll out one or more trained policies on the same seeded scenes and write per-episode "
        "outcomes (resumable), results.json/csv and a markdown table in the paper's layout.",
    )
    p.add_argument("--run", action="append", required=True, type=Path,
                   help="training run folder or checkpoint; repeat for several methods")
    p.add_argument("--tasks", nargs="+", default=None,
                   help="tasks to evaluate (default: the tasks the runs were trained on, each on the splits that "
                   "define objects for it; every task of the split for runs whose training data is unknown)")
    p.add_argument("--split", nargs="+", default=["seen", "unseen"], choices=SPLITS, metavar="SPLIT",
                   help=f"object splits to evaluate ({', '.join(SPLITS)}), one outcome folder each and one "
                   "combined table (default: seen unseen)")
    p.add_argument("--episodes", type=int_range(1, 10**6), default=25, help="episodes per task and repeat (paper: 25)")
    p.add_argument("--repeats", type=int_range(1, 1000), default=5, help="repeats with different scenes (paper: 5)")
    p.add_argument("--workers", type=int_range(1, 256), default=WORKERS, help="parallel rollout processes")
    add_backend_arguments(p)  # --backend local|ray, --ray-address
    add_config_arguments(p, EvalSettings)  # --device, --grounder, --resolution, --max-steps, --splits
    p.add_argument("--gifs", type=count, default=0,
                   help="save front-camera GIFs of this many episodes per method and task: of repeat 0 in episode "
                   "order, the first ceil(N/2) successes and floor(N/2) failures (topped up from the other kind), "
                   "rolled out again after the evaluation")
    p.add_argument("--out", type=Path, default=None,
                   help="with one --split: the folder of its outcomes and tables (default: FIRST_RUN/eval_SPLIT "
                   "for a training run folder, else runs/eval/NAME/eval_SPLIT: never models/ or the package); "
                   "with several: the parent of one eval_SPLIT folder per split and of the combined table "
                   "eval_summary.md/.json (default: the first run's folder, or runs/eval/NAME)")
    p.set_defaults(func="abm.cli.commands.evaluate:run")
