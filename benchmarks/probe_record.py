"""Put one probe arm's keyframe accuracy and rollouts into a probe's JSON (``docs/results/zoom_probe.json``).

A probe's JSON holds ``{"fit": [...], "accuracy": [...], "rollouts": [...]}``; ``benchmarks/rotation_fit.py
--probe`` fills ``fit``; this fills the other two from the files the measurements write, replacing the rows
of the same arm and step:

* ``--accuracy FILE``: the ``--out`` JSON of ``benchmarks/keyframe_accuracy.py`` (one checkpoint): rows
  ``{arm, step, task, split, keyframe, scenes, yaw_error_deg, position_error_cm}`` (medians);
* ``--rollouts FILE``: the ``eval_summary.json`` (or a ``results.json``) of ``abm eval``: rows
  ``{arm, step, task, split, successes, episodes}``.

The probe's tables on its page are written from this JSON by its spec's report (``abm experiment run zoom_probe
--stages report``: the ``probe_fit``, ``probe_accuracy`` and ``probe_rollouts`` sections).

Usage: python benchmarks/probe_record.py --probe docs/results/zoom_probe.json --arm two-stage+crop --step 3000
           [--accuracy acc.json] [--rollouts runs/.../eval_summary.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def accuracy_rows(summary: list[dict[str, Any]], arm: str, step: int) -> list[dict[str, Any]]:
    """Probe rows from ``keyframe_accuracy.py``'s summary rows (one method)."""
    methods = {r["method"] for r in summary}
    if len(methods) != 1:
        raise SystemExit(f"the accuracy file holds {len(methods)} methods ({sorted(methods)}); record one at a time")
    return [{"arm": arm, "step": step, "task": r["task"], "split": r["split"], "keyframe": r["kind"],
             "scenes": r["n"], "yaw_error_deg": round(r["rotation_deg_median"], 1),
             "position_error_cm": round(r["position_cm_median"], 2)} for r in summary]


def rollout_rows(rates: list[dict[str, Any]], arm: str, step: int) -> list[dict[str, Any]]:
    """Probe rows from ``abm eval``'s success rates (one method)."""
    methods = {r["method"] for r in rates}
    if len(methods) != 1:
        raise SystemExit(f"the rollout file holds {len(methods)} methods ({sorted(methods)}); record one at a time")
    return [{"arm": arm, "step": step, "task": r["task"], "split": r["split"], "successes": r["successes"],
             "episodes": r["episodes"]} for r in rates]


def replace_rows(probe: dict[str, Any], key: str, rows: list[dict[str, Any]]) -> None:
    """Replace ``probe[key]``'s rows of the rows' arm and step by ``rows``."""
    arms = {(r["arm"], r["step"]) for r in rows}
    probe[key] = [r for r in probe.get(key, []) if (r["arm"], r.get("step")) not in arms] + rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--probe", type=Path, required=True)
    p.add_argument("--arm", default=None)
    p.add_argument("--step", type=int, default=None)
    p.add_argument("--accuracy", type=Path, default=None)
    p.add_argument("--rollouts", type=Path, default=None)
    args = p.parse_args()
    if args.accuracy is None and args.rollouts is None:
        p.error("give --accuracy and/or --rollouts")
    if args.arm is None or args.step is None:
        p.error("--accuracy / --rollouts need --arm and --step")
    probe = json.loads(args.probe.read_text()) if args.probe.exists() else {"fit": [], "accuracy": [], "rollouts": []}
    if args.accuracy is not None:
        rows = accuracy_rows(json.loads(args.accuracy.read_text())["summary"], args.arm, args.step)
        replace_rows(probe, "accuracy", rows)
        print(f"accuracy: {len(rows)} rows of {args.arm} at step {args.step}")
    if args.rollouts is not None:
        rows = rollout_rows(json.loads(args.rollouts.read_text()), args.arm, args.step)
        replace_rows(probe, "rollouts", rows)
        print(f"rollouts: {len(rows)} rows of {args.arm} at step {args.step}")
    args.probe.write_text(json.dumps(probe, indent=1) + "\n")


if __name__ == "__main__":
    main()
