"""LeRobot side by side: abm's exports read and trained on by LeRobot itself, and a dataset written with
LeRobot's API imported into abm. Run it with the Python of an environment that holds both abm and LeRobot
0.6.1 (the recipe is in docs/datasets.md, "Using the exports from LeRobot 0.6.1"):

    OMP_NUM_THREADS=1 python benchmarks/lerobot_roundtrip.py --out runs/lerobot_roundtrip \
        [--episodes 2] [--resolution 64] [--steps 5] [--json docs/results/lerobot_roundtrip.json]

Steps, each timed and checked:

1. generate: ``--episodes`` dense demonstrations of ``--task`` with abm's scripted expert (``abm data generate
   --dense``), or the abm episodes of ``--data``;
2. export: a dense export (``fps`` 10, H.264 videos) and a keyframe export of them (``abm data export``);
3. load: both with ``lerobot.datasets.LeRobotDataset`` (the videos decoded by LeRobot's default backend), with
   an action chunk by ``delta_timestamps``; the first frame's camera image against abm's own image;
4. train: LeRobot's ACT, from scratch (no pretrained backbone: its ImageNet weights come from
   download.pytorch.org), state and action normalised by the exported quantiles (``QUANTILES``: q01 / q99),
   ``--steps`` optimiser steps on the CPU, then one ``select_action``;
5. write: one camera of the first episode written frame by frame with ``LeRobotDataset.create`` /
   ``add_frame`` / ``save_episode`` / ``finalize`` (camera as LeRobot's default video, depth, calibration,
   TCP pose and gripper in ``observation.state``), as a LeRobot user would record it;
6. import: that dataset into abm (``abm data import --format lerobot --task``, as a command in its own
   process: in this one, which imported Hugging Face ``datasets``, pyarrow reads LeRobot's 2-D columns as an
   extension type abm's import refuses), its keyframes against the expert's.

Everything is written under ``--out`` (a new or empty folder). Nothing is downloaded (``HF_HUB_OFFLINE=1``
unless set). The record names the working folder ``OUT``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np


def _step(results: dict[str, Any], name: str):
    """A context manager for one step: records its seconds in ``results["seconds"][name]`` and, when it fails,
    its error in ``results["failed"][name]`` and carries on (the steps after it that need it fail too)."""

    class _Step:
        def __enter__(self):
            self.start = time.perf_counter()
            print(f"[{name}] ...", flush=True)

        def __exit__(self, kind, error, trace):
            seconds = round(time.perf_counter() - self.start, 1)
            results.setdefault("seconds", {})[name] = seconds
            if error is not None:
                results.setdefault("failed", {})[name] = f"{type(error).__name__}: {error}"
                traceback.print_exception(error)
            print(f"[{name}] {seconds} s" + (f" FAILED: {error!r}" if error else ""), flush=True)
            return isinstance(error, Exception)

    return _Step()


def versions() -> dict[str, str]:
    """Python, torch, LeRobot and abm (commit of the checkout the script runs from, when it is one)."""
    import lerobot
    import torch

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True,
                                cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    from abm.machine import describe_machine

    return {"python": platform.python_version(), "torch": torch.__version__, "lerobot": lerobot.__version__,
            "abm_commit": commit, "machine": describe_machine()}


def generate(out: Path, task: str, episodes: int, resolution: int, fps: float) -> Path:
    """``episodes`` dense demonstrations of ``task`` (seen split) under ``out``."""
    from abm.data.generate import generate as generate_episodes

    report = generate_episodes(task, "seen", episodes, out, resolution=resolution, dense_fps=fps, progress=False)
    print(f"  {report}")
    return out


def load_with_lerobot(root: Path, chunk: int, camera: str, reference_rgb: np.ndarray) -> dict[str, Any]:
    """Open an export with LeRobot's own ``LeRobotDataset`` and read frames with an action chunk; compare the
    first frame of ``camera`` with ``reference_rgb`` (abm's own image, ``(H, W, 3)``, 0-255)."""
    import torch
    from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(repo_id=f"abm/{root.name}", root=root)
    delta = {"action": [i / meta.fps for i in range(chunk)]}
    start = time.perf_counter()
    dataset = LeRobotDataset(repo_id=f"abm/{root.name}", root=root, delta_timestamps=delta)
    opened = time.perf_counter() - start
    start = time.perf_counter()
    items = [dataset[i] for i in range(0, len(dataset), max(1, len(dataset) // 8))]
    per_item = (time.perf_counter() - start) / len(items)
    item = items[0]
    summary: dict[str, Any] = {
        "episodes": dataset.num_episodes, "frames": dataset.num_frames, "fps": meta.fps,
        "cameras": list(meta.camera_keys), "video_cameras": list(meta.video_keys),
        "video_backend": getattr(dataset, "_video_backend", None) if meta.video_keys else None,  # 0.6.1: private
        "tasks": list(meta.tasks.index), "item_keys": len(item),
        "shapes": {k: list(v.shape) for k, v in item.items() if isinstance(v, torch.Tensor) and
                   k in ("observation.state", "action", "action_is_pad", *meta.camera_keys[:1])},
        "action_chunk_padded": int(items[-1]["action_is_pad"].sum()),
        "stats_keys_action": sorted(meta.stats["action"]),
        "seconds_to_open": round(opened, 1), "seconds_per_item": round(per_item, 3),
    }
    decoded = item[f"observation.images.{camera}"].permute(1, 2, 0).numpy() * 255.0  # LeRobot: CHW in [0, 1]
    summary["first_frame_rgb_mean_abs_error"] = round(float(np.abs(decoded - reference_rgb).mean()), 2)
    return summary


def train_act(root: Path, steps: int, batch_size: int) -> dict[str, Any]:
    """LeRobot's ACT, from scratch, ``steps`` optimiser steps on the CPU, state and action normalised with the
    export's quantiles; then one action chosen for a frame of the dataset."""
    import torch
    from lerobot.configs.types import NormalizationMode
    from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    torch.manual_seed(0)
    meta = LeRobotDatasetMetadata(repo_id=f"abm/{root.name}", root=root)
    cfg = ACTConfig(device="cpu", chunk_size=10, n_action_steps=10, pretrained_backbone_weights=None,
                    push_to_hub=False,
                    normalization_mapping={"VISUAL": NormalizationMode.MEAN_STD,
                                           "STATE": NormalizationMode.QUANTILES,
                                           "ACTION": NormalizationMode.QUANTILES})
    policy = make_policy(cfg, ds_meta=meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    dataset = LeRobotDataset(repo_id=f"abm/{root.name}", root=root,
                             delta_timestamps=resolve_delta_timestamps(cfg, meta))
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=True, num_workers=0, drop_last=True)
    optimizer = torch.optim.AdamW(policy.parameters(), lr=cfg.optimizer_lr, weight_decay=cfg.optimizer_weight_decay)
    policy.train()
    losses, batches = [], iter(loader)
    start = time.perf_counter()
    for _ in range(steps):
        try:
            batch = next(batches)
        except StopIteration:
            batches = iter(loader)
            batch = next(batches)
        loss, _ = policy.forward(pre(batch))
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        losses.append(round(loss.item(), 3))
    seconds_per_step = (time.perf_counter() - start) / steps
    policy.eval()
    policy.reset()
    frame = {k: v.unsqueeze(0) if isinstance(v, torch.Tensor) else [v] for k, v in dataset[0].items()
             if k in cfg.input_features or k == "task"}
    with torch.no_grad():
        action = post(policy.select_action(pre(frame)))
    return {"policy": "act", "parameters_M": round(sum(p.numel() for p in policy.parameters()) / 1e6, 1),
            "input_features": sorted(cfg.input_features), "normalization": "state, action: QUANTILES (q01/q99)",
            "batch_size": batch_size, "steps": steps, "losses": losses,
            "seconds_per_step": round(seconds_per_step, 2), "select_action_shape": list(action.shape),
            "action_finite": bool(np.all(np.isfinite(action.numpy())))}


def write_with_lerobot(episode_file: Path, root: Path, camera: str) -> dict[str, Any]:
    """One camera of an abm dense episode recorded into a new dataset with LeRobot's writing API."""
    from lerobot.datasets import LeRobotDataset

    from abm.data.episode_store import load_episode
    from abm.geometry.rotations import matrix_to_quat

    episode = load_episode(episode_file)
    assert episode.trajectory is not None
    obs = episode.trajectory.observations
    h, w = obs[0].cameras[camera].rgb.shape[:2]
    names = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open"]
    features = {
        f"observation.images.{camera}": {"dtype": "video", "shape": (h, w, 3),
                                         "names": ["height", "width", "channels"]},
        f"geometry.depth.{camera}": {"dtype": "float32", "shape": (h, w), "names": ["height", "width"]},
        f"geometry.intrinsics.{camera}": {"dtype": "float32", "shape": (3, 3), "names": None},
        f"geometry.extrinsics.{camera}": {"dtype": "float32", "shape": (4, 4), "names": None},
        "observation.state": {"dtype": "float32", "shape": (8,), "names": names},
        "action": {"dtype": "float32", "shape": (8,), "names": [f"joint{i}" for i in range(1, 8)] + ["gripper"]},
    }
    dataset = LeRobotDataset.create(repo_id="user/pick_block", fps=round(episode.trajectory.fps), features=features,
                                    root=root, robot_type="franka_panda")
    for o, action in zip(obs, episode.trajectory.joint_actions, strict=True):
        cam = o.cameras[camera]
        pose = o.gripper_pose
        state = np.concatenate([pose[:3, 3], matrix_to_quat(pose[:3, :3]), [o.gripper_open]]).astype(np.float32)
        dataset.add_frame({f"observation.images.{camera}": cam.rgb, f"geometry.depth.{camera}": cam.depth,
                           f"geometry.intrinsics.{camera}": cam.intrinsics.astype(np.float32),
                           f"geometry.extrinsics.{camera}": cam.extrinsics.astype(np.float32),
                           "observation.state": state, "action": action.astype(np.float32),
                           "task": episode.instruction})
    dataset.save_episode()
    dataset.finalize()
    info = json.loads((root / "meta" / "info.json").read_text())
    codec = info["features"][f"observation.images.{camera}"].get("info", {}).get("video.codec")
    return {"frames": len(obs), "camera": camera, "video_codec": codec, "expert_keyframes": len(episode.steps),
            "expert_positions": [a.position.tolist() for _, a in episode.steps]}


def import_into_abm(root: Path, out: Path, task: str, expert_positions: list[list[float]]) -> dict[str, Any]:
    """``abm data import --format lerobot --task TASK`` of a dataset abm did not write, run as the command in
    its own process (as a user runs it); the found keyframes against the expert's (for each expert keyframe,
    the nearest imported keyframe's distance)."""
    from abm.data.episode_store import load_episode

    args = ["data", "import", "--format", "lerobot", str(root), "--out", str(out), "--task", task]
    done = subprocess.run([sys.executable, "-c", "from abm.cli import main; raise SystemExit(main())", *args],
                          capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"abm {' '.join(args)} failed: {done.stderr.strip().splitlines()[-1:]}")
    files = sorted(out.rglob("episode_*.h5"))
    episode = load_episode(files[0])
    found = np.array([a.position for _, a in episode.steps])
    expert = np.asarray(expert_positions)
    nearest = np.linalg.norm(expert[:, None] - found[None], axis=-1).min(1)
    return {"command": "abm " + " ".join(args), "output": done.stdout.strip().splitlines()[-1:],
            "episodes": len(files), "keyframes_found": len(episode.steps), "instruction": episode.instruction,
            "cameras": sorted(episode.steps[0][0].cameras),
            "expert_keyframe_to_nearest_found_cm": [round(float(d) * 100, 1) for d in nearest]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="a new or empty working folder")
    parser.add_argument("--data", type=Path, help="abm dense episodes to use instead of generating")
    parser.add_argument("--task", default="pick_block")
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=64, help="camera resolution of generated episodes (px)")
    parser.add_argument("--fps", type=float, default=10.0, help="dense recording rate (Hz)")
    parser.add_argument("--steps", type=int, default=5, help="ACT training steps")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--json", type=Path, help="write the results here (e.g. docs/results/lerobot_roundtrip.json)")
    args = parser.parse_args(argv)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")  # the datasets are local: LeRobot must not ask the Hub
    if args.out.exists() and any(args.out.iterdir()):
        parser.error(f"--out {args.out} is not empty")

    from abm.data.episode_store import EpisodeStore, load_episode
    from abm.data.lerobot import export_lerobot

    results: dict[str, Any] = {"command": " ".join(["python", *sys.argv]), "versions": versions()}
    print(json.dumps(results["versions"]))
    data = args.data
    if data is None:
        data = args.out / "abm_episodes"
        with _step(results, "generate"):
            generate(data, args.task, args.episodes, args.resolution, args.fps)
    first = EpisodeStore(data).episodes[0].path
    episode = load_episode(first)
    assert episode.trajectory is not None, f"{first} has no dense trajectory (generate with --dense)"
    camera = sorted(episode.trajectory.observations[0].cameras)[0]
    references = {"dense": episode.trajectory.observations[0].cameras[camera].rgb.astype(np.float64),
                  "keyframes": episode.steps[0][0].cameras[camera].rgb.astype(np.float64)}
    exports = {"dense": args.out / "export_dense", "keyframes": args.out / "export_keyframes"}
    for frames, root in exports.items():
        with _step(results, f"export_{frames}"):
            report = export_lerobot(data, root, frames=frames, progress=False)
            results[f"export_{frames}"] = {"summary": report.summary(root.name), "MB": round(report.bytes / 1e6, 2)}
    for frames, root in exports.items():
        with _step(results, f"lerobot_load_{frames}"):
            chunk = 10 if frames == "dense" else 3
            results[f"lerobot_load_{frames}"] = load_with_lerobot(root, chunk, camera, references[frames])
    with _step(results, "lerobot_train_act"):
        results["lerobot_train_act"] = train_act(exports["dense"], args.steps, args.batch_size)
    with _step(results, "lerobot_write"):
        written = write_with_lerobot(first, args.out / "lerobot_written", camera)
        expert_positions = written.pop("expert_positions")
        results["lerobot_write"] = written
    if "lerobot_write" in results:
        with _step(results, "abm_import_lerobot_written"):
            results["abm_import_lerobot_written"] = import_into_abm(
                args.out / "lerobot_written", args.out / "imported", args.task, expert_positions)
    # the working folder as OUT, so the record names no path of this machine
    text = json.dumps(results, indent=1).replace(str(args.out.resolve()), "OUT").replace(str(args.out), "OUT")
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    return 1 if results.get("failed") else 0


if __name__ == "__main__":
    sys.exit(main())
