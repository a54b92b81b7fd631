"""``abm zoo``: the committed model zoo (``models/``) — list it, verify it, and see the paper's finding without
training.

* ``abm zoo list`` prints the index (``models/index.json``, written by ``abm experiment run paper_tables``)
  and checks every file against its recorded sha256;
* ``abm zoo eval`` evaluates the zoo's abm and rvt models on seen and unseen objects of the paper's 8 tasks
  (:data:`~abm.evaluation.settings.ZOO_EVAL_TASKS`, fixed before looking at any result) through the full pipeline
  (simulator, grounding, policy, executor) and prints one table. The default budget is 5 episodes per task and
  split: 160 rollouts (its measured time: ``abm zoo eval --help``, from :mod:`abm.measured`).

Of each method (abm, rvt) it runs the model the README's tables show: the newest edition's marked ``compared`` in
the index (abm_clip_v3, rvt_clip_v3 in the committed zoo); in a zoo without such marks, the first model of the index
that the zoo can run, a CLIP-grounded one when the benchmark CLIP is in the zoo too, else one that needs no CLIP
(abm_oracle). ``--models NAME ...`` names the models instead (e.g. an earlier edition's: abm_clip_v2 rvt_clip_v2).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import WORKERS, int_range
from abm.evaluation.settings import ZOO_EVAL_EPISODES, ZOO_EVAL_MAX_STEPS, ZOO_EVAL_TASKS
from abm.measured import zoo_eval_text
from abm.zoo import DEFAULT_ZOO


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("zoo", help="the committed model zoo: list and verify it, or evaluate its models",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="zoo_command", metavar="ZOO_COMMAND", required=True)
    lst = sub.add_parser("list", help="print the zoo's models and verify their sha256")
    lst.add_argument("--zoo", type=Path, default=DEFAULT_ZOO, help=f"zoo folder (default {DEFAULT_ZOO})")
    lst.set_defaults(func="abm.cli.commands.zoo:list_zoo")
    ev = sub.add_parser("eval", help="evaluate the zoo's abm and rvt models on seen and unseen objects "
                        f"({zoo_eval_text(results=False)})")
    ev.add_argument("--zoo", type=Path, default=DEFAULT_ZOO, help=f"zoo folder (default {DEFAULT_ZOO})")
    ev.add_argument("--tasks", nargs="+", default=list(ZOO_EVAL_TASKS),
                    help="tasks to evaluate (default: the paper's 8 tasks)")
    ev.add_argument("--episodes", type=int_range(1, 10_000), default=ZOO_EVAL_EPISODES,
                    help=f"seeded episodes per task and split (default {ZOO_EVAL_EPISODES}: "
                         f"{zoo_eval_text(results=False)})")
    ev.add_argument("--workers", type=int_range(1, 256), default=WORKERS,
                    help=f"parallel rollout processes (default {WORKERS})")
    ev.add_argument("--max-steps", type=int_range(1, 100), default=ZOO_EVAL_MAX_STEPS,
                    help=f"keyframes per episode (default {ZOO_EVAL_MAX_STEPS})")
    ev.add_argument("--models", nargs="+", default=[], metavar="NAME",
                    help="the zoo's models to evaluate, by their index name (e.g. abm_clip_v3 rvt_clip_v3; default: "
                         "of abm and rvt each the newest edition's compared model, as the README's tables)")
    ev.add_argument("--out", type=Path, default=Path("out/zoo"), help="output folder (default out/zoo)")
    ev.set_defaults(func="abm.cli.commands.zoo:evaluate_zoo")
