"""Quality of a CLIP model for grounding: zero-shot classification on held-out renders, and the Object Mask
Field on ABM-Bench scenes of every task and split, per normalisation and threshold.

Usage: python benchmarks/clip_quality.py --clip-model runs/clip_bench [--seeds 5] [--resolution 128]
                                         [--heldout DIR] [--no-random] [--tasks T ...] [--json OUT.json]
                                         [--figure OUT.png]

* **Zero-shot classification**: every object crop of the held-out renders (``DIR``, default
  ``MODEL/data_heldout``; rendered with ``abm.clip_training.data`` and other seeds than the training set
  when missing) is classified by comparing its CLS image embedding with ``"a photo of a X"`` for every
  catalog object X (top-1), and by the mean MaskCLIP patch feature over the object's pixels ("dense").
  Also per object group: objects of some task's seen split, of an unseen split only, of a compositional
  split only.
* **Mask field** (threshold sweep): the first observation of ``make_env(task, split, seed)`` for every task
  and split of ``splits.yaml`` and seeds ``0..S-1``; X comes from decomposing the instruction, the ground
  truth is the simulator segmentation of the task's target (``target_point_mask``). Per point of the
  fused cloud: the CLIP Feature Cloud as the grounder computes it, then each normalisation (raw, minmax,
  softmax against the default negatives at logit scale 100) and threshold, with the grounder's fallback
  (top-1 point when nothing passes). Metrics per case: point precision, recall and IoU of the mask, hit
  (mask centre in the target's box + 1 cm), found, and "top-1" (the highest-scoring point is on the
  target; threshold-free). Cases where the target has no point in the cloud are skipped.
* Baselines: the same architecture with random weights (``--no-random`` skips it), and the oracle (the
  simulator segmentation; IoU 1 by construction, checked).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import ClipGrounder, OracleGrounder, load_clip
from abm.grounding.config import DEFAULT_NEGATIVES
from abm.grounding.grounders import target_point_mask
from abm.grounding.mask_field import negative_prompts, normalize_heatmap, threshold_heatmap
from abm.grounding.metrics import score_mask
from abm.language import clip_prompt, decompose_instruction

THRESHOLDS: dict[str, tuple[float, ...]] = {
    "raw": (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8),
    "minmax": (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95),
    "softmax": (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9),
}


def random_like(backbone: Any, seed: int = 0) -> Any:
    """The same architecture, tokenizer and image normalisation with freshly initialised weights."""
    from dataclasses import replace

    from transformers import CLIPModel

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = CLIPModel(backbone.model.config).eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return replace(backbone, model=model, name=f"random-init:{backbone.name}", fingerprint="")


# --------------------------------------------------------------------------------------------------
# Zero-shot classification
# --------------------------------------------------------------------------------------------------
def object_groups() -> dict[str, str]:
    """Object name -> "seen" / "unseen" / "compositional" (the first split listing it, in that order)."""
    from abm.sim.splits import load_splits

    groups: dict[str, str] = {}
    tasks = load_splits().tasks
    for split in ("seen", "unseen", "compositional"):
        for lists in tasks.values():
            for name in lists.get(split, []):
                groups.setdefault(name, split)
    return groups


def zero_shot(backbones: dict[str, Any], heldout: Path) -> list[dict[str, Any]]:
    from abm.clip_training.data import load_dataset
    from abm.clip_training.train import zero_shot_accuracy

    data = load_dataset(heldout)
    groups = object_groups()
    rows = []
    for label, backbone in backbones.items():
        res = zero_shot_accuracy(backbone, data)
        row = {"model": label, "crops": res["crops"], "classes": res["classes"], "accuracy": res["accuracy"],
               "dense_accuracy": res["dense_accuracy"]}
        for group in ("seen", "unseen", "compositional", "other"):
            accs = [a for n, a in res["per_class"].items() if groups.get(n, "other") == group]
            row[f"accuracy_{group}_objects"] = float(np.mean(accs)) if accs else math.nan
        row["worst_classes"] = sorted(res["per_class"].items(), key=lambda kv: kv[1])[:5]
        rows.append(row)
    return rows


# --------------------------------------------------------------------------------------------------
# Mask field on ABM-Bench scenes
# --------------------------------------------------------------------------------------------------
def bench_cases(tasks: list[str] | None, seeds: int, resolution: int
                ) -> Iterator[tuple[str, str, int, Any, dict, str, str]]:
    """``(task, split, seed, observation, object names, X, true target name)`` of every task and split."""
    from abm.sim.env import make_env
    from abm.sim.splits import load_splits

    for task, lists in load_splits().tasks.items():
        if tasks and task not in tasks:
            continue
        for split in lists:
            for seed in range(seeds):
                env = make_env(task, split=split, seed=seed, resolution=resolution)
                try:
                    obs = env.reset()
                    names, instruction, truth = dict(env.object_names), env.instruction, env.target_names[0]
                finally:
                    env.close()
                target, _skill = decompose_instruction(instruction)
                yield task, split, seed, obs, names, target, truth


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    sel = mask > 0.5
    union = int((sel | truth).sum())
    return int((sel & truth).sum()) / union if union else math.nan


def thresholds(norm: str) -> tuple[float, ...]:
    """The threshold sweep of a normalisation (``softmax@S`` = softmax at logit scale S)."""
    return THRESHOLDS[norm.split("@")[0]]


def evaluate_case(grounder: ClipGrounder, obs: Any, cloud: Any, target: str, truth: np.ndarray,
                  softmax_scales: tuple[float, ...] = (100.0,)) -> dict[tuple[str, float], dict[str, float]]:
    """Metrics of every (normalisation, threshold) for one case; softmax once per logit scale."""
    feats = torch.from_numpy(grounder.point_features(obs, cloud))
    text = torch.from_numpy(grounder.text_features([clip_prompt(target)]))[0]
    negs = torch.from_numpy(grounder.text_features(negative_prompts(DEFAULT_NEGATIVES)))
    sim = feats @ text
    neg = feats @ negs.T
    out = {}
    norms = [("raw", 100.0), ("minmax", 100.0)] + [("softmax", sc) for sc in softmax_scales]
    for norm, scale in norms:
        heat = normalize_heatmap(sim, norm, neg if norm == "softmax" else None, scale)
        top1 = float(truth[int(np.argmax(heat))])
        if norm == "softmax" and scale != 100.0:
            norm = f"softmax@{scale:.3g}"
        for thr in thresholds(norm):
            mask, found = threshold_heatmap(heat, thr, "top", 1)
            s = score_mask(cloud.xyz, mask, truth, found)
            out[(norm, thr)] = {"precision": s.precision, "recall": s.recall, "iou": iou(mask, truth),
                                "hit": float(s.hit), "found": float(found), "top1": top1,
                                "mask_fraction": float(mask.mean())}
    return out


def patch_oracle(obs: Any, cloud: Any, truth_ids: list[int], grid: tuple[int, int], fraction: float = 0.2
                 ) -> np.ndarray:
    """``(N,)`` mask of the points whose nearest patch (``grid`` per camera) is at least ``fraction`` target
    pixels: the best a perfect patch classifier can do through nearest-patch lifting (resolution bound)."""
    out = np.zeros(len(cloud), np.float32)
    for ci, name in enumerate(cloud.camera_names):
        seg = np.isin(obs.camera(name).segmentation, truth_ids)
        h, w = seg.shape
        rows = np.minimum(((np.arange(h) + 0.5) * grid[0] / h).astype(int), grid[0] - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * grid[1] / w).astype(int), grid[1] - 1)
        share = np.zeros(grid)
        count = np.zeros(grid)
        np.add.at(share, (rows[:, None], cols[None, :]), seg)
        np.add.at(count, (rows[:, None], cols[None, :]), 1)
        good = share / np.maximum(count, 1) >= fraction
        sel = cloud.camera_index == ci
        px = cloud.pixels[sel]
        out[sel] = good[rows[px[:, 0]], cols[px[:, 1]]]
    return out


def nanmean(values: list[float]) -> float:
    vals = [v for v in values if not math.isnan(v)]
    return float(np.mean(vals)) if vals else math.nan


def mask_quality(backbones: dict[str, Any], tasks: list[str] | None, seeds: int, resolution: int,
                 input_size: tuple[int, int] | None = None
                 ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int]:
    """(summary rows per model / normalisation / threshold, per-case rows, skipped cases)."""
    from abm.grounding.grounders import match_object_ids

    grounders = {label: ClipGrounder(backbone=b, cache_features=False, input_size=input_size)
                 for label, b in backbones.items()}
    first = next(iter(backbones.values()))
    side = input_size or (first.image_size, first.image_size)
    grid = (side[0] // first.patch_size, side[1] // first.patch_size)
    oracle = OracleGrounder()
    workspace = Workspace()
    per_case: list[dict[str, Any]] = []
    skipped = 0
    for task, split, seed, obs, names, target, true_name in bench_cases(tasks, seeds, resolution):
        cloud = fuse_cameras(obs, workspace)
        truth = target_point_mask(obs, cloud, true_name, names)
        if not truth.any():
            skipped += 1
            continue
        oracle_iou = iou(oracle.ground(obs, cloud, target, names).mask, truth)
        bound = patch_oracle(obs, cloud, match_object_ids(true_name, names), grid)
        bound_row = {"patch_oracle_iou": iou(bound, truth), "patch_oracle_precision": float(truth[bound > 0].mean())
                     if bound.any() else math.nan, "patch_oracle_recall": float(bound[truth].mean())}
        for label, grounder in grounders.items():
            scales = (100.0, round(grounder.backbone.logit_scale, 2))
            for (norm, thr), m in evaluate_case(grounder, obs, cloud, target, truth, scales).items():
                per_case.append({"model": label, "task": task, "split": split, "seed": seed, "target": target,
                                 "normalization": norm, "threshold": thr, "oracle_iou": oracle_iou,
                                 **bound_row, **m})
    summary = []
    keys = sorted({(r["model"], r["normalization"], r["threshold"]) for r in per_case})
    for model, norm, thr in keys:
        rows = [r for r in per_case if (r["model"], r["normalization"], r["threshold"]) == (model, norm, thr)]
        summary.append({"model": model, "normalization": norm, "threshold": thr, "n": len(rows),
                        **{k: nanmean([r[k] for r in rows]) for k in (
                            "precision", "recall", "iou", "hit", "found", "top1", "mask_fraction", "oracle_iou",
                            "patch_oracle_iou", "patch_oracle_precision", "patch_oracle_recall")}})
    return summary, per_case, skipped


def best_per_normalization(summary: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """(model, normalisation) -> the summary row of its threshold with the highest mean IoU."""
    best: dict[tuple[str, str], dict[str, Any]] = {}
    for row in summary:
        key = (row["model"], row["normalization"])
        if key not in best or row["iou"] > best[key]["iou"]:
            best[key] = row
    return best


def figure(backbone: Any, path: Path, tasks: list[str] | None, resolution: int, camera: str = "front",
           normalization: str = "softmax", threshold: float = 0.7) -> None:
    """One row per task (seed 0, first split): camera image | similarity heatmap | mask, with X in the label."""
    from PIL import Image

    from abm.grounding import MaskFieldConfig
    from abm.grounding.visualize import blend, colormap, hstack, label, upscale, vstack

    grounder = ClipGrounder(backbone=backbone, config=MaskFieldConfig(normalization=normalization,
                                                                       threshold=threshold))
    rows, done = [], set()
    for task, split, _seed, obs, names, target, _truth in bench_cases(tasks, 1, resolution):
        if task in done or len(done) == 6:
            continue
        done.add(task)
        cloud = fuse_cameras(obs, Workspace())
        field = grounder.ground(obs, cloud, target, names)
        frame = obs.camera(camera)
        sel = cloud.camera_index == cloud.camera_names.index(camera)
        heat = np.zeros(frame.rgb.shape[:2], np.float32)
        mask = np.zeros(frame.rgb.shape[:2], np.float32)
        heat[cloud.pixels[sel, 0], cloud.pixels[sel, 1]] = field.heatmap[sel]
        mask[cloud.pixels[sel, 0], cloud.pixels[sel, 1]] = field.mask[sel]
        red = np.zeros_like(frame.rgb)
        red[..., 0] = 255
        rows.append(hstack([label(upscale(frame.rgb, 2), f"{task}/{split}: {target}"),
                            label(upscale(blend(frame.rgb, colormap(heat), 0.2 + 0.7 * heat), 2),
                                  f"{normalization} heatmap"),
                            label(upscale(blend(frame.rgb, red, 0.8 * mask), 2), f"mask (>= {threshold:g})")]))
    path.parent.mkdir(parents=True, exist_ok=True)
    half = (len(rows) + 1) // 2
    Image.fromarray(hstack([vstack(rows[:half]), vstack(rows[half:] or rows[:1])])).save(path)


def fmt(v: float, digits: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip-model", required=True, help="trained model folder (or any load_clip name)")
    parser.add_argument("--heldout", type=Path, default=None, help="held-out renders (default MODEL/data_heldout)")
    parser.add_argument("--heldout-shards", type=int, default=4, help="shards to render when --heldout is missing")
    parser.add_argument("--seeds", type=int, default=5, help="scenes per task and split (seeds 0..S-1)")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (default: every task of splits.yaml)")
    parser.add_argument("--resolution", type=int, default=128, help="camera resolution (px)")
    parser.add_argument("--no-random", action="store_true", help="skip the random-weights baseline")
    parser.add_argument("--input-size", type=int, default=None,
                        help="resize camera images to this side for CLIP (default: the model's native size)")
    parser.add_argument("--skip-zero-shot", action="store_true")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None, help="write every number here")
    parser.add_argument("--figure", type=Path, default=None,
                        help="also write a PNG: front camera, heatmap and mask of the trained model per task")
    parser.add_argument("--figure-normalization", default="softmax", choices=list(THRESHOLDS))
    parser.add_argument("--figure-threshold", type=float, default=0.7)
    parser.add_argument("--figure-tasks", nargs="+",
                        default=["pick_block", "place_food", "close_jar", "water_plants", "place_wine", "insert_peg"])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    start = time.perf_counter()

    trained = load_clip(args.clip_model, device="cpu")
    backbones = {"trained": trained}
    if not args.no_random:
        backbones["random weights"] = random_like(trained)
    result: dict[str, Any] = {"model": args.clip_model, "seeds": args.seeds, "resolution": args.resolution}

    if not args.skip_zero_shot:
        heldout = args.heldout or Path(args.clip_model) / "data_heldout"
        if not (heldout / "dataset.json").is_file() or not list(heldout.glob("shard_*.npz")):
            from abm.clip_training.data import build_dataset

            build_dataset(heldout, args.heldout_shards, base_seed=1, workers=2)
        rows = zero_shot(backbones, heldout)
        result["zero_shot"] = rows
        print(f"\nZero-shot classification of held-out object crops ({heldout}):\n")
        print("| model | crops | classes | top-1 (CLS) | top-1 (pooled dense) | seen objects | unseen objects | "
              "compositional-only objects |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['model']} | {r['crops']} | {r['classes']} | {fmt(r['accuracy'])} | "
                  f"{fmt(r['dense_accuracy'])} | {fmt(r['accuracy_seen_objects'])} | "
                  f"{fmt(r['accuracy_unseen_objects'])} | {fmt(r['accuracy_compositional_objects'])} |")
        print("worst classes (trained):", rows[0]["worst_classes"])

    input_size = (args.input_size, args.input_size) if args.input_size else None
    summary, per_case, skipped = mask_quality(backbones, args.tasks, args.seeds, args.resolution, input_size)
    result.update(mask_summary=summary, mask_cases=per_case, skipped_cases=skipped)
    n_cases = len({(r["task"], r["split"], r["seed"]) for r in per_case})
    print(f"\nMask field on {n_cases} ABM-Bench scenes ({skipped} skipped: target not in the cloud); "
          f"oracle IoU {fmt(nanmean([r['oracle_iou'] for r in per_case]))}; patch-oracle bound (a perfect "
          f"patch classifier through nearest-patch lifting) IoU {fmt(summary[0]['patch_oracle_iou'])}, "
          f"precision {fmt(summary[0]['patch_oracle_precision'])}, recall {fmt(summary[0]['patch_oracle_recall'])}"
          f":\n")
    print("| model | normalisation | threshold | precision | recall | IoU | hit rate | found rate | top-1 point | "
          "mask share of cloud |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in summary:
        print(f"| {r['model']} | {r['normalization']} | {r['threshold']:g} | {fmt(r['precision'])} | "
              f"{fmt(r['recall'])} | {fmt(r['iou'])} | {fmt(r['hit'], 2)} | {fmt(r['found'], 2)} | "
              f"{fmt(r['top1'], 2)} | {fmt(r['mask_fraction'])} |")
    best = best_per_normalization(summary)
    print("\nBest threshold per normalisation (by mean IoU):\n")
    print("| model | normalisation | best threshold | IoU | precision | recall | hit rate | IoU at 0.7 |")
    print("|---|---|---|---|---|---|---|---|")
    for (model, norm), r in sorted(best.items()):
        at07 = next((s["iou"] for s in summary if (s["model"], s["normalization"], s["threshold"]) ==
                     (model, norm, 0.7)), math.nan)
        print(f"| {model} | {norm} | {r['threshold']:g} | {fmt(r['iou'])} | {fmt(r['precision'])} | "
              f"{fmt(r['recall'])} | {fmt(r['hit'], 2)} | {fmt(at07)} |")
    # per task / split for the trained model at each normalisation's best threshold
    print("\nTrained model per task and split (IoU at each normalisation's best threshold; top-1 point):\n")
    norms = sorted({r["normalization"] for r in summary if r["model"] == "trained"})
    print("| task | split | n | " + " | ".join(f"IoU {n} @{best[('trained', n)]['threshold']:g}" for n in norms)
          + " | top-1 point (softmax) |")
    print("|---|---|---|" + "---|" * (len(norms) + 1))
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in per_case:
        if r["model"] == "trained":
            groups[(r["task"], r["split"])].append(r)
    for (task, split), rows in groups.items():
        cells = []
        for n in norms:
            thr = best[("trained", n)]["threshold"]
            cells.append(fmt(nanmean([r["iou"] for r in rows if r["normalization"] == n and r["threshold"] == thr])))
        top1 = nanmean([r["top1"] for r in rows if r["normalization"] == "softmax" and r["threshold"] == 0.7])
        n_seeds = len({r["seed"] for r in rows})
        print(f"| {task} | {split} | {n_seeds} | " + " | ".join(cells) + f" | {fmt(top1, 2)} |")
    if args.figure:
        figure(trained, args.figure, args.figure_tasks, args.resolution, normalization=args.figure_normalization,
               threshold=args.figure_threshold)
        print(f"wrote {args.figure}")
    result["seconds"] = round(time.perf_counter() - start, 1)
    print(f"\n{time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
