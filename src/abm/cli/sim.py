"""``abm tasks``: list the ABM-Bench tasks with their instruction templates and object splits."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser("tasks", help="list benchmark tasks, instruction templates and splits")
    parser.add_argument("--splits", type=Path, default=None, help="object split YAML replacing the default")
    parser.add_argument("--task", default=None, help="show only this task")
    parser.set_defaults(func="abm.cli.commands.sim:_tasks")
