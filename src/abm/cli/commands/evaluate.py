"""``abm eval`` (the parser: :mod:`abm.cli.evaluate`; the evaluation: :func:`abm.evaluation.session.run_evaluation`)."""

from __future__ import annotations

import argparse

from abm.configuration import config_from_args
from abm.evaluation.session import EvalRequest, run_evaluation
from abm.evaluation.settings import EvalSettings


def eval_request(args: argparse.Namespace) -> EvalRequest:
    """The evaluation ``abm eval``'s flags ask for."""
    return EvalRequest(runs=tuple(args.run), tasks=tuple(args.tasks) if args.tasks else None, splits=tuple(args.split),
                       episodes=args.episodes, repeats=args.repeats, workers=args.workers, gifs=args.gifs,
                       out=args.out, settings=config_from_args(EvalSettings, args), backend=args.backend,
                       ray_address=args.ray_address)


def run(args: argparse.Namespace) -> int:
    run_evaluation(eval_request(args))
    return 0
