"""How well a policy fits the rotation labels of its own training keyframes, per task and keyframe kind.

The command line of the ``rotation_fit`` diagnosis (:class:`abm.evaluation.diagnose.rotation_fit.RotationFit`):
every keyframe of the demonstrations (the tasks and seen split a run trained on) is predicted teacher-forced, as in
training, without and with the training augmentation; the table gives the mean cross-entropy (nats) of the roll,
pitch and yaw bins per task and keyframe kind, beside the yaw's chance line for the keyframes' symmetry (ln 36
two-fold, ln 18 four-fold, 0 round) and the prior of a model that knows only the task and the kind. ``--json``
also writes the rows.

Usage: python benchmarks/rotation_fit.py --run RUN --data DATA [--tasks place_food take_off_pan] [--json OUT]

A probe's learning curve: ``--probe docs/results/zoom_probe.json --arm two-stage --step 1000`` also puts the rows
into the probe's ``fit`` list (replacing those of the same arm and step); ``--rows OUT`` reads rows written by
``--json`` earlier instead of measuring again.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli import configure_logging
from abm.evaluation.diagnose.rotation_fit import RotationFit, read_rows, table


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, type=Path, help="run folder, checkpoint or zoo file")
    p.add_argument("--data", required=True, type=Path, help="the episode store the run trained on")
    p.add_argument("--tasks", nargs="+", default=None, help="tasks to score (default: every task in DATA)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows here")
    p.add_argument("--rows", type=Path, default=None, help="read the rows of an earlier --json instead of measuring")
    p.add_argument("--probe", type=Path, default=None, help="a probe's JSON ({fit, accuracy, rollouts}) to put the "
                   "rows into, with --arm and --step")
    p.add_argument("--arm", default=None, help="with --probe: the arm's name (single-stage, two-stage)")
    p.add_argument("--step", type=int, default=None, help="with --probe: the checkpoint's training step")
    args = p.parse_args()
    if args.probe is not None and (args.arm is None or args.step is None):
        p.error("--probe needs --arm and --step")
    configure_logging()
    request = RotationFit(model=args.run, data=args.data, tasks=tuple(args.tasks) if args.tasks else None,
                          out=args.json, probe=args.probe, arm=args.arm, step=args.step)
    rows = read_rows(args.rows) if args.rows is not None else request.measure()
    print(table(rows))
    request.write(rows)


if __name__ == "__main__":
    main()
