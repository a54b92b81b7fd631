"""``abm experiment``: run an experiment spec (``configs/experiments/NAME.yaml``) stage by stage, or see where
it stands.

* ``abm experiment run SPEC [--stages ...] [--runs ...]`` runs what is left of the stages data → ground →
  train → export → eval → diagnose → report (``--stages carry`` copies unfinished work into the committed
  carry); every stage resumes, also on a fresh clone from what the experiment commits;
* ``abm experiment status SPEC`` lists every job: done, running, left or blocked, with its minutes;
* ``abm experiment list`` names the built-in specs.

SPEC is a YAML file or a built-in name (paper_tables, seen_unseen, clip_grounder, put_in_container,
rotation_probe, quickstart). Paths in a spec are relative to --root (default: the current folder, the checkout).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import int_range
from abm.experiments.spec import EXTRA_STAGES, STAGES
from abm.ray_pool import add_backend_arguments


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", help="the experiment: a YAML file or a built-in name (abm experiment list)")
    p.add_argument("--root", type=Path, default=Path("."),
                   help="the folder the spec's paths start from, where the commands run (default: the current folder)")
    p.add_argument("--out", type=Path, default=None,
                   help="the working folder (default: the spec's out, e.g. runs/NAME)")
    p.add_argument("--runs", nargs="+", default=None, metavar="RUN",
                   help="only these runs (and their evaluations and diagnoses; default: every run of the spec)")


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("experiment", help="run an experiment spec stage by stage (resumable), or its status",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="experiment_command", metavar="EXPERIMENT_COMMAND", required=True)
    run = sub.add_parser("run", help="run what is left of an experiment's stages")
    _common(run)
    run.add_argument("--stages", nargs="+", default=list(STAGES), choices=[*STAGES, *EXTRA_STAGES], metavar="STAGE",
                     help=f"stages to run, in the engine's order ({' '.join(STAGES)}; 'carry' copies unfinished "
                          "trainings and evaluations into the committed carry)")
    run.add_argument("--source", type=Path, default=None,
                     help="the checkout whose code the jobs run (e.g. a worktree pinned at a commit; default: the "
                          "one abm is imported from)")
    run.add_argument("--threads", type=int_range(1, 256), default=None, metavar="N",
                     help="torch threads of every training (default: the spec's resources.threads_each, and a "
                          "training left alone takes the idle slots' too); give it when another run shares the "
                          "machine, so a lone training does not take its cores")
    run.add_argument("--dry-run", action="store_true", help="print the jobs left and their commands, run nothing")
    add_backend_arguments(run)  # --backend local|ray, --ray-address
    run.set_defaults(func="abm.cli.commands.experiment:run")
    status = sub.add_parser("status", help="every job of an experiment: done, running, left or blocked, with times")
    _common(status)
    status.set_defaults(func="abm.cli.commands.experiment:status")
    lst = sub.add_parser("list", help="the built-in experiment specs")
    lst.set_defaults(func="abm.cli.commands.experiment:list_specs")
