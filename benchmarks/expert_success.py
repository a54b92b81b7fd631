"""Measure the scripted experts' success rate per task and split on ABM-Bench.

Usage::

    python benchmarks/expert_success.py --episodes 50 [--tasks place_food pick_block place_wine]
        [--splits seen unseen compositional] [--workers 1] [--seed 0] [--verbose]

Each task runs on those of ``--splits`` that the split file defines for it (the compositional tasks
only have the ``compositional`` split). Cameras are not rendered (rendering does not change the
physics), so this measures control only. Prints a Markdown table (task, split, successes / episodes,
%, mean seconds per episode); ``--verbose`` also prints one line per finished episode.
"""

from __future__ import annotations

import argparse
import platform
import time
from concurrent.futures import ProcessPoolExecutor


def _run(job: tuple[str, str, int]) -> tuple[str, str, int, bool, list[str], float]:
    from abm.sim.env import make_env, run_expert

    task, split, seed = job
    start = time.perf_counter()
    try:
        with make_env(task, split, seed, resolution=32) as env:
            episode = run_expert(env, record=False)
    except Exception as err:  # noqa: BLE001 - a crashing episode counts as a failure, the run goes on
        return task, split, seed, False, [f"error: {err!r}"], time.perf_counter() - start
    return task, split, seed, episode.success, episode.metadata["motions"], time.perf_counter() - start


def main() -> None:
    from abm.sim.splits import load_splits
    from abm.sim.tasks import TASKS

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS))
    parser.add_argument("--splits", nargs="+", default=["seen", "unseen", "compositional"])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="first seed; episodes use seed .. seed+N-1")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--verbose", action="store_true", help="print every finished episode")
    args = parser.parse_args()
    defined = load_splits().tasks
    pairs = [(t, s) for t in args.tasks for s in args.splits if s in defined.get(t, {})]
    jobs = [(t, s, args.seed + i) for t, s in pairs for i in range(args.episodes)]
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.workers) as pool:
        for res in pool.map(_run, jobs, chunksize=4):
            results.append(res)
            if args.verbose:
                print(f"{res[0]} {res[1]} seed {res[2]}: {'ok' if res[3] else 'FAILED'} ({res[5]:.1f} s)",
                      flush=True)
            if not res[3]:
                print(f"failed: {res[0]} {res[1]} seed {res[2]}: {res[4]}", flush=True)
    total = time.perf_counter() - start
    print(f"\nmachine: {platform.processor() or platform.machine()}, {args.workers} worker(s), "
          f"{total:.0f} s total\n")
    print("| task | split | success | rate | s/episode |")
    print("|---|---|---|---|---|")
    for task, split in pairs:
        rows = [r for r in results if r[0] == task and r[1] == split]
        ok = sum(r[3] for r in rows)
        secs = sum(r[5] for r in rows) / max(1, len(rows))
        print(f"| {task} | {split} | {ok}/{len(rows)} | {100 * ok / max(1, len(rows)):.0f}% | {secs:.1f} |")


if __name__ == "__main__":
    main()
