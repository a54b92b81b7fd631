"""Cameras and arms behind small interfaces (:class:`abm.robot.kinds.Camera`, :class:`abm.robot.kinds.Arm`), so
the deployment loop runs on real hardware, a recording, the simulator or a dry run alike.

* A camera has ``read() -> dict[str, CameraFrame]`` (RGB, metric depth, intrinsics, camera-to-base
  extrinsics) and ``object_names`` (segmentation id -> name; empty for real cameras).
* An arm has ``state() -> (gripper_pose (4, 4), gripper_open in [0, 1])`` and ``move(action) -> status``.

Implemented here: :class:`ReplayCamera` (frames recorded with :func:`record_observations`),
:class:`DryRunArm` (only logs), and :class:`SimRobot` (the MuJoCo scene as camera and arm).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from abm.errors import ConfigError
from abm.files import atomic_path, write_text_atomic
from abm.types import CameraFrame, KeyframeAction, Observation

log = logging.getLogger(__name__)


def record_observations(observations: Sequence[Observation], folder: str | Path,
                        object_names: Mapping[int, str] | None = None, instruction: str = "") -> Path:
    """Write observations as a replayable recording: ``meta.json`` and one ``step_XXX.npz`` per observation."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for k, obs in enumerate(observations):
        arrays: dict[str, np.ndarray] = {"gripper_pose": obs.gripper_pose, "gripper_open": np.array(obs.gripper_open)}
        for name, frame in obs.cameras.items():
            arrays.update({f"{name}/rgb": frame.rgb, f"{name}/depth": frame.depth,
                           f"{name}/intrinsics": frame.intrinsics, f"{name}/extrinsics": frame.extrinsics})
            if frame.segmentation is not None:
                arrays[f"{name}/segmentation"] = frame.segmentation
        with atomic_path(folder / f"step_{k:03d}.npz") as tmp, tmp.open("wb") as fh:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]  # numpy's stub: **arrays vs allow_pickle
    meta = {"steps": len(observations), "cameras": sorted(observations[0].cameras) if observations else [],
            "object_names": {str(k): v for k, v in (object_names or {}).items()}, "instruction": instruction}
    write_text_atomic(folder / "meta.json", json.dumps(meta, indent=1))
    return folder


class ReplayCamera:
    """Frames of a recording, one step per :meth:`read` (the last step repeats once the recording ends)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        meta_path = self.folder / "meta.json"
        if not meta_path.is_file():
            raise ConfigError(f"{self.folder} is not a camera recording (no meta.json); make one with "
                              "abm.robot.record_observations")
        meta = json.loads(meta_path.read_text())
        self.names: list[str] = list(meta["cameras"])
        self.steps = int(meta["steps"])
        self.object_names = {int(k): v for k, v in meta.get("object_names", {}).items()}
        self.instruction = str(meta.get("instruction", ""))
        self.index = 0

    @classmethod
    def from_config(cls, options: Mapping[str, object]) -> ReplayCamera:
        """From the robot file's ``cameras`` section: ``{kind: replay, path: FOLDER}``."""
        return cls(str(options["path"]))

    def _load(self, k: int) -> dict[str, np.ndarray]:
        with np.load(self.folder / f"step_{k:03d}.npz", allow_pickle=False) as data:
            return {key: data[key] for key in data.files}

    def read(self) -> dict[str, CameraFrame]:
        data = self._load(min(self.index, self.steps - 1))
        self.index += 1
        return {n: CameraFrame(rgb=data[f"{n}/rgb"], depth=data[f"{n}/depth"], intrinsics=data[f"{n}/intrinsics"],
                               extrinsics=data[f"{n}/extrinsics"], segmentation=data.get(f"{n}/segmentation"))
                for n in self.names}

    def recorded_gripper(self) -> tuple[np.ndarray, float]:
        """Gripper pose and opening of the recording's first step (a dry-run arm's start state)."""
        data = self._load(0)
        return data["gripper_pose"], float(data["gripper_open"])


class DryRunArm:
    """Moves nothing: logs each commanded keyframe and pretends it was reached."""

    def __init__(self, pose: np.ndarray | None = None, gripper_open: float = 1.0) -> None:
        self.pose = np.eye(4) if pose is None else np.asarray(pose, np.float64)
        self.gripper_open = float(gripper_open)
        self.commands: list[KeyframeAction] = []

    def state(self) -> tuple[np.ndarray, float]:
        return self.pose.copy(), self.gripper_open

    def stop(self) -> None:
        log.info("dry run: stop")

    def move(self, action: KeyframeAction) -> str:
        self.commands.append(action)
        log.info("dry run: would move to %s, gripper %s", np.round(action.position, 3).tolist(),
                 "open" if action.gripper_open else "closed")
        self.pose, self.gripper_open = action.matrix, float(action.gripper_open)
        return "dry-run"


class SimRobot:
    """The MuJoCo scene of one ABM-Bench episode as both camera and arm."""

    def __init__(self, task: str, split: str = "seen", seed: int = 0, resolution: int = 128) -> None:
        from abm.sim.env import TaskEnv  # mujoco (optional `sim` extra): only the simulated robot needs it

        self.env = TaskEnv(task, split, seed, resolution)
        self._obs = self.env.reset()
        self.object_names = dict(self.env.object_names)
        self.instruction = self.env.instruction
        self.names = list(self._obs.cameras)

    def read(self) -> dict[str, CameraFrame]:
        return dict(self._obs.cameras)

    def state(self) -> tuple[np.ndarray, float]:
        return self._obs.gripper_pose.copy(), self._obs.gripper_open

    def move(self, action: KeyframeAction) -> str:
        self._obs, _, info = self.env.step(action)
        return str(info["motion"].status)

    def success(self) -> bool:
        return self.env.success()

    def close(self) -> None:
        self.env.close()
