"""Grounding quality against ground-truth segmentation, per grounder and object split.

Usage: python benchmarks/grounding_quality.py [--source synthetic|sim|both] [--seeds 5]
                                              [--clip-model tiny] [--normalizations raw minmax softmax]
                                              [--tasks place_food pick_block ...] [--json OUT.json]

Scenes: the built-in synthetic scene (every block in turn is the target; split "synthetic") and, when
``abm.sim`` provides ``make_env``, the first observation of each simulated task and split (the target is
the episode's target object). Grounders: the oracle (sanity check: must be perfect) and the CLIP grounder
with each normalisation. Metrics (``abm.grounding.metrics``): point precision and recall of the mask,
distance from the mask centre to the target centre (m), hit rate (mask centre inside the target's
bounding box + 1 cm) and found rate. ``--clip-model`` defaults to the tiny random model, whose numbers only
exercise the pipeline; pass real weights (hub name in the local cache or a directory) for meaningful ones.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import (
    ClipGrounder,
    MaskFieldConfig,
    OracleGrounder,
    decompose_instruction,
    load_clip,
    target_point_mask,
)
from abm.grounding.metrics import score_mask, summarize
from abm.render.synthetic import synthetic_scene

SIM_TASKS = ("place_food", "pick_block", "put_in_shelf", "place_wine", "water_plants", "close_jar", "insert_peg",
             "take_off_pan", "place_block_in_plate", "pick_food_to_target")


Case = tuple[str, Any, dict[int, str], str, str]


def synthetic_cases(seeds: int) -> Iterator[Case]:
    """(split, observation, object names, instruction, true target name) for every block of every scene."""
    for seed in range(seeds):
        obs, names = synthetic_scene(seed=seed)
        for target in names.values():
            yield "synthetic", obs, names, f"put the {target} on the target", target


def _find(obj: Any, *attrs: str) -> Any:
    for attr in attrs:
        value = obj
        for part in attr.split("."):
            value = getattr(value, part, None)
            if value is None:
                break
        if value is not None:
            return value
    return None


def sim_cases(tasks: list[str], seeds: int, resolution: int) -> Iterator[Case]:
    """Cases from the MuJoCo benchmark, when it is available (skipped with a note otherwise)."""
    try:
        from abm.sim.env import make_env
    except Exception as err:  # noqa: BLE001 - any import problem means "no simulator here"
        print(f"note: abm.sim.env.make_env is not available ({type(err).__name__}: {err}); sim cases skipped")
        return
    for task in tasks:
        for split in ("seen", "unseen", "compositional"):
            status = yield from _split_cases(make_env, task, split, seeds, resolution)
            if status == "no task":
                break


def _split_cases(make_env: Any, task: str, split: str, seeds: int, resolution: int) -> Iterator[Case]:
    for seed in range(seeds):
        try:
            env = make_env(task, split=split, seed=seed, resolution=resolution)
            obs = env.reset()
        except KeyError as err:  # unknown task
            print(f"note: {task} skipped ({err})")
            return "no task"
        except Exception as err:  # noqa: BLE001 - a task/split combination may not exist
            print(f"note: {task}/{split} skipped ({type(err).__name__}: {str(err)[:120]})")
            return "no split"
        names = _find(env, "object_names", "episode.object_names") or {}
        targets = _find(env, "target_names", "episode.target_names") or []
        instruction = _find(env, "instruction", "episode.instruction")
        close = getattr(env, "close", None)
        if callable(close):
            close()
        if not names or not targets or not instruction:
            print(f"note: {task}/{split}: env exposes no object_names / target_names / instruction; skipped")
            return "no split"
        yield f"{task}/{split}", obs, dict(names), str(instruction), str(targets[0])
    return "ok"


def fmt(value: float, digits: int = 3) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=("synthetic", "sim", "both"), default="both")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--tasks", nargs="+", default=list(SIM_TASKS))
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--clip-model", default="tiny", help="'tiny' (random), a hub name or a local directory")
    parser.add_argument("--normalizations", nargs="+", default=["raw", "minmax", "softmax"])
    parser.add_argument("--threshold", type=float, default=0.7)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", default=None, help="also write the summary table as JSON here")
    args = parser.parse_args()

    backbone = load_clip(args.clip_model, device=args.device)
    grounders: dict[str, Any] = {"oracle": OracleGrounder()}
    for norm in args.normalizations:
        config = MaskFieldConfig(normalization=norm, threshold=args.threshold)
        grounders[f"clip[{backbone.name}]/{norm}"] = ClipGrounder(backbone=backbone, config=config)

    cases = []
    if args.source in ("synthetic", "both"):
        cases += list(synthetic_cases(args.seeds))
    if args.source in ("sim", "both"):
        cases += list(sim_cases(args.tasks, args.seeds, args.resolution))
    scores: dict[tuple[str, str], list] = defaultdict(list)
    workspace = Workspace()
    for split, obs, names, instruction, true_name in cases:
        target, _skill = decompose_instruction(instruction)  # X as the method sees it
        cloud = fuse_cameras(obs, workspace)
        truth = target_point_mask(obs, cloud, true_name, names)
        for gname, grounder in grounders.items():
            field = grounder.ground(obs, cloud, target, names)
            scores[(gname, split)].append(score_mask(cloud.xyz, field.mask, truth, field.found))

    print(f"{len(cases)} cases; threshold {args.threshold}")
    print("| grounder | split | n | precision | recall | centre dist (m) | hit rate | found rate |")
    print("|---|---|---|---|---|---|---|---|")
    table = []
    for (gname, split), items in scores.items():
        s = summarize(items)
        table.append({"grounder": gname, "split": split, **s})
        print(f"| {gname} | {split} | {s['count']} | {fmt(s['precision'])} | {fmt(s['recall'])} | "
              f"{fmt(s['center_distance_m'])} | {fmt(s['hit_rate'], 2)} | {fmt(s['found_rate'], 2)} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(table, f, indent=2)


if __name__ == "__main__":
    main()
