"""Size and CPU cost of the IFD baseline's CLIP point features: a patch table with each point's row in it (what the
samples and the grounding cache hold) against the per-point ``(N, F)`` float16 array they held before.

For one first observation of each benchmark task, the CLIP grounder of a zoo IFD model lifts the features of the
cloud the model sees (:func:`abm.grounding.conditioning.condition_cloud`). Both forms are written as grounding-cache
entries (the table keeps only the rows some point uses, :meth:`LiftedFeatures.compact`; the array is the entry
written before tables), then timed in process CPU seconds with one torch thread:

* ``load``: reading the entries and building the samples' feature tensors (``np.load``, :func:`cloud_sample`);
* ``inputs``: collating the samples into one batch and the policy's ``model_inputs`` (the virtual views and the
  features of the rows some pixel shows);
* ``forward``: the coarse network on those inputs.

The per-point form is the same work the code did before tables (its rows are the points). Both forms must give the
same network output, else the script fails.

    OMP_NUM_THREADS=1 python benchmarks/ifd_features.py --model ifd_clip_v3 --record docs/results/ifd_features.json

``--data STORE --cache CACHE`` (a grounding cache of ``abm data ground --data STORE --cache CACHE --features``)
measures the training data side instead: the cache is copied once as the per-point arrays entries held before
tables, and a :class:`~abm.data.keyframes.KeyframeDataset` over each (augmentation on, the default 2 GiB keyframe
memory) is drawn from as a training draws: one pass over every keyframe (what the memory keeps), then ``--draws``
random draws timed in process CPU seconds (the steady state of a training: a kept keyframe is only augmented, any
other is read, fused and grounded again)::

    OMP_NUM_THREADS=1 python benchmarks/ifd_features.py --data runs/paper_v2/data --cache CACHE \
        --record docs/results/ifd_features.json
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from abm.data.keyframes import _cached_features
from abm.evaluation.policies import load_policy
from abm.evaluation.settings import EvalSettings
from abm.grounding.conditioning import ConditionedCloud, condition_cloud
from abm.grounding.feature_cloud import LiftedFeatures
from abm.samples import Sample, cloud_sample, collate
from abm.sim.env import make_env
from abm.sim.split_file import read_splits
from abm.sim.tasks import TASKS
from abm.types import Observation


def _cpu(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """Mean process CPU seconds of ``fn`` over ``repeats`` calls, and its last result."""
    start = time.process_time()
    for _ in range(repeats):
        out = fn()
    return (time.process_time() - start) / repeats, out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="ifd_clip_v3", help="zoo model or checkpoint of an IFD policy")
    p.add_argument("--tasks", nargs="*", default=None, help="one scene per task (default: every task with a "
                   "seen split)")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats of each stage")
    p.add_argument("--record", type=Path, default=None, help="write the result (one JSON object) here")
    p.add_argument("--data", type=Path, default=None, help="an episode store: measure the training data side")
    p.add_argument("--cache", type=Path, default=None, help="with --data: its grounding cache of CLIP features")
    p.add_argument("--clip-model", default="models/benchmark-clip", help="with --data: the CLIP the cache was "
                   "grounded with (abm data ground --clip-model)")
    p.add_argument("--draws", type=int, default=400, help="with --data: timed random draws")
    args = p.parse_args()
    torch.set_num_threads(1)
    if args.data is not None:
        if args.cache is None:
            raise SystemExit("--data needs --cache (abm data ground --data DATA --cache CACHE --features)")
        print(json.dumps(data_side(args.data, args.cache, args.clip_model, args.draws, args.record), indent=1))
        return
    model = Path("models") / f"{args.model}.pt" if not args.model.endswith(".pt") else Path(args.model)
    policy = load_policy(model, EvalSettings())
    if not policy.spec.clip_features:
        raise SystemExit(f"{model} is a {policy.spec.name!r} policy; this benchmark needs an IFD one")
    splits = read_splits(None, TASKS)
    tasks = args.tasks or [t for t in sorted(TASKS) if "seen" in splits.tasks.get(t, {})]
    observed: list[tuple[Observation, ConditionedCloud, LiftedFeatures]] = []
    for i, task in enumerate(tasks):
        env = make_env(task, "seen", seed=i)
        obs = env.reset()
        env.close()
        scene = condition_cloud(obs, env.instruction, policy.workspace, grounder=policy.grounder, features=True,
                                split=policy.sample_options()["split"], camera_names=policy.camera_names)
        assert scene.features is not None  # asked for
        observed.append((obs, scene, scene.features))
    with tempfile.TemporaryDirectory() as tmp:
        entries: dict[str, list[Path]] = {"table": [], "per_point": []}
        for i, (_obs, _scene, lifted) in enumerate(observed):
            compact = lifted.compact()
            for form, arrays in (("table", {"feature_table": compact.table.astype(np.float16),
                                            "feature_row": compact.index.astype(np.int32)}),
                                 ("per_point", {"features": lifted.dense().astype(np.float16)})):
                path = Path(tmp) / f"{form}_{i}.npz"
                np.savez(path, **arrays)
                entries[form].append(path)
        result: dict[str, Any] = {
            "commit": _commit(),
            "model": args.model, "scenes": len(observed), "threads": 1,
            "points_per_scene": round(float(np.mean([len(f) for _, _, f in observed]))),
            "table_rows_per_scene": round(float(np.mean([len(np.unique(f.index)) for _, _, f in observed]))),
            "feature_width": int(observed[0][2].table.shape[1]),
        }
        outputs = {}
        for form, paths in entries.items():
            def load(paths: list[Path] = paths) -> list[Sample]:
                samples = []
                for path, (obs, scene, _lifted) in zip(paths, observed, strict=True):
                    with np.load(path) as data:
                        features = _cached_features(data)
                    samples.append(cloud_sample(dataclasses.replace(scene, features=features), obs.gripper_open,
                                                obs.gripper_pose[:3, 3]))
                return samples

            def inputs_of(samples: list[Sample]) -> dict[str, torch.Tensor]:
                return policy.model_inputs(collate(samples))

            load_s, samples = _cpu(load, args.repeats)
            with torch.no_grad():
                inputs_s, inputs = _cpu(functools.partial(inputs_of, samples), args.repeats)
                forward_s, out = _cpu(functools.partial(policy.model, **inputs), args.repeats)
            outputs[form] = out
            result[form] = {"bytes_per_entry": round(float(np.mean([f.stat().st_size for f in paths]))),
                            "load_s_per_scene": round(load_s / len(paths), 5),
                            "inputs_s_per_batch": round(inputs_s, 4), "forward_s_per_batch": round(forward_s, 4),
                            "visible_rows_per_scene": round(float((inputs["ifd_index"].flatten(1).amax(1) + 1)
                                                                  .float().mean()))}
    for field in ("heatmap", "rotation", "gripper", "collision"):
        torch.testing.assert_close(getattr(outputs["table"], field), getattr(outputs["per_point"], field), atol=1e-5,
                                   rtol=0, msg=field)
    result["same_output"] = True
    print(json.dumps(result, indent=1))
    if args.record is not None:  # the data side's measurement (--data) stays
        kept = json.loads(args.record.read_text()).get("data_side") if args.record.exists() else None
        args.record.write_text(json.dumps({**result, **({"data_side": kept} if kept else {})}, indent=1) + "\n")


def _commit() -> str:
    """This tree's short commit (the script's own repository, whatever the working folder)."""
    return subprocess.run(["git", "-C", str(Path(__file__).parent), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True, check=False).stdout.strip()


def data_side(data: Path, cache: Path, clip_model: str, draws: int, record: Path | None) -> dict[str, Any]:
    """The training data side (module docstring): keyframes kept, CPU s per draw, bytes of the cache, per form;
    added to ``record``'s object under ``"data_side"`` when given."""
    from abm.data.episode_store import EpisodeStore
    from abm.data.keyframes import EpisodeSource, KeyframeDataset
    from abm.geometry import Workspace
    from abm.grounding.config import grounder_from_flags
    from abm.policy.config import PolicyConfig

    store = EpisodeStore(data)
    source = EpisodeSource(store, store.select(tasks=None, splits=["seen"]))
    config = PolicyConfig()
    workspace = Workspace(config.workspace_center, config.workspace_size)  # the policies' default cube
    grounder = grounder_from_flags("clip", clip_model)  # as abm data ground --clip-model CLIP_MODEL configures it
    result: dict[str, Any] = {"commit": _commit(), "data": str(data), "draws": draws, "memory_mb": 2048}
    with tempfile.TemporaryDirectory(dir=cache.parent) as tmp:
        dense = Path(tmp)
        for entry in sorted(cache.glob("*.npz")):  # the per-point arrays entries held before tables
            with np.load(entry) as stored:
                np.savez(dense / entry.name, features=stored["feature_table"][stored["feature_row"]])
        for form, folder in (("table", cache), ("per_point", dense)):
            ds = KeyframeDataset(source, workspace, grounder, split=False, features=True, cache_dir=folder)
            for i in range(len(ds)):  # the first pass: what the memory keeps
                ds[(i, i)]
            rng = np.random.default_rng(0)
            picks = rng.integers(0, len(ds), draws)
            start = time.process_time()
            for n, i in enumerate(picks):
                ds[(int(i), len(ds) + n)]
            seconds = (time.process_time() - start) / draws
            result[form] = {"cache_bytes": sum(f.stat().st_size for f in folder.glob("*.npz")),
                            "keyframes": len(ds), "kept_in_memory": len(ds._memory),
                            "cpu_s_per_draw": round(seconds, 4)}
    if record is not None:
        recorded = json.loads(record.read_text()) if record.exists() else {}
        recorded["data_side"] = result
        record.write_text(json.dumps(recorded, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
