"""Grounding quality against ground-truth segmentation, per grounder and object split.

Usage: python benchmarks/grounding_quality.py [--source synthetic|sim|both] [--seeds 5]
                                              [--clip-model tiny] [--normalizations raw minmax softmax]
                                              [--tasks place_food pick_block ...] [--json OUT.json]
       python benchmarks/grounding_quality.py --cases runs/grounding_cases --clip-model DIR
                                              [--configs NAME ...] [--random-configs NAME ...] [--seeds 10]
                                              [--out docs/results/grounding_quality.json] [--doc docs/grounding.md]

With ``--cases`` (observations cached by ``benchmarks/grounding_cases.py``: the first observation of every
task, split and seed of ABM-Bench) it compares grounding *configurations* (:data:`CONFIGS`: per-point field
with each dense-feature option and input size, 3-D proposals with each scoring), per task and split:
point IoU, precision, recall, hit rate, top-1 point and seconds per observation. It writes every record
to ``--out`` and the generated tables between the ``grounding_quality`` markers of ``--doc`` (written by
:mod:`abm.experiments.report.pages.grounding_configs`).

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
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

from abm.experiments.report.pages.grounding_configs import block, fmt, markdown, nan_mean, write_block
from abm.geometry import Workspace, fuse_cameras
from abm.grounding import ClipGrounder, MaskFieldConfig, OracleGrounder, load_clip, target_point_mask
from abm.grounding.metrics import score_mask, summarize
from abm.language import decompose_instruction
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


# --------------------------------------------------------------------------------------------------
# Configuration sweep on cached ABM-Bench observations (issue 26)
# --------------------------------------------------------------------------------------------------
FIELD = {"mode": "field", "normalization": "softmax", "threshold": 0.7}
CONFIGS: dict[str, dict[str, Any]] = {
    "oracle": {"kind": "oracle"},
    "field (maskclip)": {**FIELD, "dense_mode": "maskclip"},
    "field (clearclip)": {**FIELD, "dense_mode": "clearclip"},
    "field (sclip)": {**FIELD, "dense_mode": "sclip"},
    "field (naclip)": {**FIELD, "dense_mode": "naclip"},
    "field (maskclip, 256 input)": {**FIELD, "dense_mode": "maskclip", "input_size": 256},
    "field (maskclip, 128+256)": {**FIELD, "dense_mode": "maskclip", "scales": [256]},
    "proposals (dense)": {"mode": "proposals", "proposals": {"scoring": "dense"}},
    "proposals (crop)": {"mode": "proposals", "proposals": {"scoring": "crop"}},
    "proposals (combined)": {"mode": "proposals", "proposals": {"scoring": "combined"}},
    "proposals (combined, no split)": {"mode": "proposals", "proposals": {"scoring": "combined", "split": False}},
    "proposals (crop, no split)": {"mode": "proposals", "proposals": {"scoring": "crop", "split": False}},
    "proposals (combined, 256 input)": {"mode": "proposals", "input_size": 256, "proposals": {"scoring": "combined"}},
}
"""Named grounding configurations: ``build_grounder({"kind": "clip", **options})`` (or the oracle)."""


def build_config_grounder(options: dict[str, Any], backbone: Any) -> Any:
    """The grounder of one :data:`CONFIGS` entry on ``backbone``, with no feature cache (honest timing)."""
    options = dict(options)
    kind = options.pop("kind", "clip")
    if kind == "oracle":
        return OracleGrounder()
    from abm.grounding import build_grounder

    return build_grounder({"kind": "clip", "cache_features": False, **options}, backbone=backbone)


def sweep(cases: list[tuple[Any, dict[str, Any]]], grounders: dict[str, Any]) -> list[dict[str, Any]]:
    """Per-case rows: config, task, split, seed, iou, precision, recall, hit, found, top1, seconds."""
    import time

    import numpy as np

    workspace = Workspace()
    rows = []
    for i, (obs, meta) in enumerate(cases):
        if i % 20 == 0:
            print(f"case {i}/{len(cases)}", flush=True)
        target, _skill = decompose_instruction(meta["instruction"])
        cloud = fuse_cameras(obs, workspace)
        truth = target_point_mask(obs, cloud, meta["target_name"], meta["object_names"])
        if not truth.any():
            continue
        for name, grounder in grounders.items():
            start = time.perf_counter()
            field = grounder.ground(obs, cloud, target, meta["object_names"])
            seconds = time.perf_counter() - start
            s = score_mask(cloud.xyz, field.mask, truth, field.found)
            sel = field.mask > 0.5
            rows.append({"config": name, "task": meta["task"], "split": meta["split"], "seed": meta["seed"],
                         "iou": float((sel & truth).sum() / (sel | truth).sum()), "precision": s.precision,
                         "recall": s.recall, "hit": float(s.hit), "found": float(s.found),
                         "top1": float(truth[int(np.argmax(field.heatmap))]), "seconds": seconds})
    return rows


METRICS = ("iou", "precision", "recall", "hit", "top1", "seconds")


def records(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One record per config, task and split (means over seeds)."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[(r["config"], r["task"], r["split"])].append(r)
    out = []
    for (config, task, split), items in groups.items():
        means = {m: nan_mean([r[m] for r in items]) for m in METRICS}
        out.append({"config": config, "task": task, "split": split, "iou": means["iou"], "hit_rate": means["hit"],
                    "top1": means["top1"], "n": len(items), "precision": means["precision"],
                    "recall": means["recall"], "seconds": means["seconds"]})
    return out


def run_sweep(args: argparse.Namespace) -> None:
    import platform
    import shlex
    import sys
    import time
    from pathlib import Path

    import torch

    from clip_quality import random_like
    from grounding_cases import load_cases

    torch.set_num_threads(args.threads)
    names = args.configs or list(CONFIGS)
    unknown = [n for n in names + (args.random_configs or []) if n not in CONFIGS]
    if unknown:
        raise SystemExit(f"unknown configs {unknown}; choose from {list(CONFIGS)}")
    backbone = load_clip(args.clip_model, device=args.device)
    grounders = {n: build_config_grounder(CONFIGS[n], backbone) for n in names}
    if args.random_configs:
        rand = random_like(backbone)
        grounders.update({f"random weights: {n}": build_config_grounder(CONFIGS[n], rand)
                          for n in args.random_configs})
    cases = list(load_cases(Path(args.cases), args.seeds, args.tasks))
    if not cases:
        raise SystemExit(f"no cached cases in {args.cases}; run benchmarks/grounding_cases.py --out {args.cases}")
    start = time.perf_counter()
    rows = sweep(cases, grounders)
    meta = {"command": "python " + shlex.join(sys.argv), "model": args.clip_model, "cases": len(cases),
            "seeds": args.seeds, "threads": args.threads, "machine": f"{platform.processor() or platform.machine()}, "
            f"{torch.get_num_threads()} torch thread(s), torch {torch.__version__}",
            "configs": {n: CONFIGS[n.removeprefix("random weights: ")] for n in grounders},
            "minutes": round((time.perf_counter() - start) / 60, 1)}
    publish([meta], records(rows), list(grounders), args.out, args.doc)


def publish(metas: list[dict[str, Any]], recs: list[dict[str, Any]], order: list[str], out: Any, doc: Any) -> None:
    """Print the tables; write the records (``out``) and the tables with how they were made (``doc``,
    :mod:`abm.experiments.report.pages.grounding_configs`)."""
    from pathlib import Path

    table = markdown(recs, order)
    print(table)
    if out:
        path = Path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = metas[0] if len(metas) == 1 else {"parts": metas}
        path.write_text(json.dumps({"meta": meta, "records": recs}, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {path}")
    if doc:
        write_block(Path(doc), block(metas, recs, order))
        print("updated", doc)


def merge(paths: list[str], out: Any, doc: Any) -> None:
    """Join the JSON files of several sweeps (e.g. run in parallel on disjoint configs) into one."""
    metas, recs, order = [], [], []
    for path in paths:
        data = json.loads(open(path, encoding="utf-8").read())
        parts = data["meta"].get("parts", [data["meta"]])
        metas += parts
        recs += data["records"]
        order += [c for m in parts for c in m["configs"] if c not in order]
    publish(metas, recs, order, out, doc)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=None,
                        help="folder of cached ABM-Bench observations: compare grounding configurations on them")
    parser.add_argument("--configs", nargs="+", default=None, help=f"with --cases: configs (default all of "
                        f"{list(CONFIGS)})")
    parser.add_argument("--random-configs", nargs="+", default=None,
                        help="with --cases: also run these configs with random weights of the same architecture")
    parser.add_argument("--threads", type=int, default=1, help="with --cases: torch threads")
    parser.add_argument("--out", default=None, help="with --cases: write the records as JSON here")
    parser.add_argument("--doc", default=None, help="with --cases: write the tables into this markdown file")
    parser.add_argument("--merge", nargs="+", default=None,
                        help="join the --out JSON files of several --cases runs into --out / --doc (no grounding)")
    parser.add_argument("--source", choices=("synthetic", "sim", "both"), default="both")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--tasks", nargs="+", default=None, help=f"tasks (default {list(SIM_TASKS)}; with --cases "
                        "every cached task)")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--clip-model", default="tiny", help="'tiny' (random), a hub name or a local directory")
    parser.add_argument("--normalizations", nargs="+", default=["raw", "minmax", "softmax"])
    parser.add_argument("--threshold", type=float, default=0.7)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", default=None, help="also write the summary table as JSON here")
    args = parser.parse_args()
    if args.merge:
        merge(args.merge, args.out, args.doc)
        return
    if args.cases:
        args.seeds = args.seeds if args.seeds != 5 else 10
        run_sweep(args)
        return
    args.tasks = args.tasks or list(SIM_TASKS)

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
