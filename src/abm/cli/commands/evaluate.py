"""``abm eval`` (the parser: :mod:`abm.cli.evaluate`; the evaluation: :func:`abm.evaluation.session.run_evaluation`)."""

from __future__ import annotations

import argparse

from abm.configuration import config_from_args
from abm.evaluation.session import EvalRequest, run_evaluation
from abm.evaluation.settings import EvalSettings


def run(args: argparse.Namespace) -> int:
    run_evaluation(EvalRequest(runs=args.run, tasks=args.tasks, splits=args.split, episodes=args.episodes,
                               repeats=args.repeats, workers=args.workers, gifs=args.gifs, out=args.out,
                               settings=config_from_args(EvalSettings, args), backend=args.backend,
                               ray_address=args.ray_address))
    return 0
