"""How well a policy fits the rotation labels of its own training keyframes, per task and keyframe kind.

Every keyframe of the demonstrations (the tasks and seen split a run trained on) is predicted teacher-forced,
as in training, without and with the training augmentation; the table gives the mean cross-entropy (nats) of
the roll, pitch and yaw bins per task and keyframe kind, beside the yaw's chance line for the keyframes'
symmetry (ln 36 two-fold, ln 18 four-fold, 0 round) and the prior of a model that knows only the task and the
kind (:mod:`abm.evaluation.rotation_fit`). ``--json`` also writes the rows.

Usage: python benchmarks/rotation_fit.py --run RUN --data DATA [--tasks place_food take_off_pan] [--json OUT]

A probe's learning curve: ``--probe docs/results/zoom_probe.json --arm two-stage --step 1000`` also puts the rows
into the probe's ``fit`` list (replacing those of the same arm and step); ``--rows OUT`` reads rows written by
``--json`` earlier instead of measuring again.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

import torch

from abm.data.episode_store import EpisodeStore
from abm.data.keyframes import EpisodeSource, KeyframeDataset
from abm.evaluation.rotation_fit import FitRow, rotation_fit
from abm.machine import describe_machine
from abm.policy import KeyframePolicy


def table(rows: list[tuple[bool, FitRow]]) -> str:
    """Markdown table of fit rows (augmentation flag, row)."""
    lines = ["| augmentation | task | keyframe | keyframes | x (roll) | y (pitch) | z (yaw) | yaw chance | yaw prior |",
             "|---|---|---|---|---|---|---|---|---|"]
    for augment, r in rows:
        x, y, z = r.cross_entropy
        lines.append(f"| {'on' if augment else 'off'} | {r.task} | {r.keyframe} | {r.keyframes} | {x:.2f} | {y:.2f} "
                     f"| {z:.2f} | {r.yaw_chance:.2f} | {r.yaw_prior:.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, help="run folder, checkpoint or zoo file")
    p.add_argument("--data", required=True, help="the episode store the run trained on")
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
    if args.rows is not None:
        saved = json.loads(args.rows.read_text())
        rows = [(r.pop("augment"), FitRow(**{**r, "cross_entropy": tuple(r["cross_entropy"])})) for r in saved]
    else:
        rows = measure(args)
    print(table(rows))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([{"augment": a, **asdict(r)} for a, r in rows], indent=1) + "\n")
    if args.probe is not None:
        add_to_probe(args.probe, args.arm, args.step, rows)


def add_to_probe(path: Path, arm: str, step: int, rows: list[tuple[bool, FitRow]]) -> None:
    """Put fit rows into a probe's JSON ``fit`` list as ``{arm, step, augment, task, keyframe, keyframes, yaw_ce,
    roll_ce, pitch_ce, yaw_chance, yaw_prior}``, replacing earlier rows of the same arm and step."""
    probe = json.loads(path.read_text()) if path.exists() else {}
    fit = [r for r in probe.get("fit", []) if (r["arm"], r["step"]) != (arm, step)]
    fit += [{"arm": arm, "step": step, "augment": a, "task": r.task, "keyframe": r.keyframe,
             "keyframes": r.keyframes, "yaw_ce": round(r.yaw, 3), "roll_ce": round(r.cross_entropy[0], 3),
             "pitch_ce": round(r.cross_entropy[1], 3), "yaw_chance": round(r.yaw_chance, 3),
             "yaw_prior": round(r.yaw_prior, 3)} for a, r in rows]
    fit.sort(key=lambda r: (r["arm"], r["step"], r["augment"]))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"fit": fit, "accuracy": probe.get("accuracy", []),
                                "rollouts": probe.get("rollouts", [])}, indent=1) + "\n")


def measure(args: argparse.Namespace) -> list[tuple[bool, FitRow]]:
    """Fit rows of ``args.run`` on its training keyframes, augmentation off then on."""
    torch.set_num_threads(1)
    started = time.perf_counter()
    policy = KeyframePolicy.from_checkpoint(args.run).eval()
    store = EpisodeStore(args.data)
    indices = store.select(tasks=args.tasks, splits=["seen"])
    if not indices:
        raise SystemExit(f"no seen episodes of {args.tasks or 'any task'} in {args.data}")
    rows: list[tuple[bool, FitRow]] = []
    for augment in (False, True):
        dataset = KeyframeDataset(EpisodeSource(store, indices), policy.workspace, policy.grounder_config,
                                  **policy.sample_options(), augment=augment, seed=0)
        rows += [(augment, r) for r in rotation_fit(policy, dataset)]
    print(f"machine: {describe_machine()}; {args.run} on {len(indices)} episodes of {args.data}; "
          f"{time.perf_counter() - started:.0f} s")
    return rows


if __name__ == "__main__":
    main()
