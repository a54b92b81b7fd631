"""``abm tasks``: list the ABM-Bench tasks with their instruction templates and object splits."""

from __future__ import annotations

import argparse

from abm.sim.splits import load_splits
from abm.sim.tasks import TASKS


def _tasks(args: argparse.Namespace) -> int:
    splits = load_splits(args.splits)
    names = sorted(TASKS)
    if args.task is not None:
        if args.task not in TASKS:
            raise TASKS.unknown(args.task)
        names = [args.task]
    print(f"object splits: {splits.path}")
    for name in names:
        cls = TASKS[name]
        kind = "evaluation only (compositional)" if cls.evaluation_only else "trainable"
        print(f"\n{name}  [{kind}]")
        for template in cls.templates:
            print(f"  template: {template.format(target='X', container='Y')}")  # Y: two-target tasks
        for split, objects in splits.tasks.get(name, {}).items():
            print(f"  {split + ':':<15}{', '.join(objects)}")
        for slot, lists in splits.slots.get(name, {}).items():
            print(f"  {slot} (Y):")
            for split, objects in lists.items():
                print(f"    {split + ':':<15}{', '.join(objects)}")
        if name not in splits.tasks:
            print("  (no objects in this split file)")
    return 0
