"""Render the first observation of every task / split / seed of ABM-Bench once and keep it as ``.npz``.

The grounding benchmarks re-run only the grounders on these files (``load_cases``), so comparing many
grounding configurations costs no simulator time. One file per case: every camera's ``rgb``, ``depth``,
``intrinsics``, ``extrinsics`` and ``segmentation``, the gripper state, and a JSON ``meta`` record (task,
split, seed, instruction, target name, object names).

Usage: python benchmarks/grounding_cases.py --out runs/grounding_cases [--seeds 10] [--resolution 128]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from abm.types import CameraFrame, Observation

CAMERA_FIELDS = ("rgb", "depth", "intrinsics", "extrinsics", "segmentation")


def save_case(path: Path, obs: Observation, meta: dict[str, Any]) -> None:
    arrays: dict[str, np.ndarray] = {"gripper_open": np.array(obs.gripper_open), "gripper_pose": obs.gripper_pose}
    for name, frame in obs.cameras.items():
        for f in CAMERA_FIELDS:
            value = getattr(frame, f)
            if value is not None:
                arrays[f"{name}/{f}"] = value
    meta = dict(meta, cameras=list(obs.cameras))
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, meta=np.array(json.dumps(meta)), **arrays)
    tmp.replace(path)


def load_case(path: Path) -> tuple[Observation, dict[str, Any]]:
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        cameras = {}
        for name in meta["cameras"]:
            kw = {f: data[f"{name}/{f}"] for f in CAMERA_FIELDS if f"{name}/{f}" in data}
            cameras[name] = CameraFrame(**kw)
        obs = Observation(cameras, float(data["gripper_open"]), data["gripper_pose"])
    meta["object_names"] = {int(k): v for k, v in meta["object_names"].items()}
    return obs, meta


def render_cases(out: Path, seeds: int, resolution: int, tasks: list[str] | None = None) -> int:
    """Render the missing cases into ``out``; returns how many files were written."""
    from abm.sim.env import make_env
    from abm.sim.splits import load_splits

    out.mkdir(parents=True, exist_ok=True)
    written = 0
    for task, lists in load_splits().tasks.items():
        if tasks and task not in tasks:
            continue
        for split in lists:
            for seed in range(seeds):
                path = out / f"{task}__{split}__{seed}.npz"
                if path.is_file():
                    continue
                env = make_env(task, split=split, seed=seed, resolution=resolution)
                try:
                    obs = env.reset()
                    meta = {"task": task, "split": split, "seed": seed, "instruction": env.instruction,
                            "target_name": env.target_names[0], "resolution": resolution,
                            "object_names": {str(k): v for k, v in dict(env.object_names).items()}}
                finally:
                    env.close()
                save_case(path, obs, meta)
                written += 1
    return written


def load_cases(folder: Path, seeds: int | None = None, tasks: list[str] | None = None
               ) -> Iterator[tuple[Observation, dict[str, Any]]]:
    """Every cached case (sorted by task, split, seed), optionally only seeds ``< seeds`` and some tasks."""
    for path in sorted(Path(folder).glob("*__*__*.npz")):
        task, split, seed = path.stem.split("__")
        if (seeds is not None and int(seed) >= seeds) or (tasks and task not in tasks):
            continue
        yield load_case(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/grounding_cases"))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--tasks", nargs="+", default=None)
    args = parser.parse_args()
    print(f"wrote {render_cases(args.out, args.seeds, args.resolution, args.tasks)} cases to {args.out}")


if __name__ == "__main__":
    main()
