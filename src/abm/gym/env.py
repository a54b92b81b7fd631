"""One ABM-Bench task and split as a :class:`gymnasium.Env` (:class:`AbmTaskEnv`), stepped one keyframe at a time.

Built on :class:`abm.sim.env.TaskEnv` (the simulator behind ``abm eval`` and the experts): each ``step`` executes
one keyframe with the arm's motion planner, as :func:`abm.sim.env.run_policy` does.

**Observation** (a :class:`gymnasium.spaces.Dict`; ``R`` is the camera resolution in pixels)::

    {"cameras": {NAME: {"rgb":          uint8   (R, R, 3),
                        "depth":        float32 (R, R)   metres along the camera's +z, 0 = no measurement
                                                         (readings past MAX_DEPTH = 100 m are clipped),
                        "segmentation": int32   (R, R)   object index of info["object_names"], -1 = none,
                        "intrinsics":   float64 (3, 3)   pinhole matrix in pixels (OpenCV),
                        "extrinsics":   float64 (4, 4)   camera-to-world transform (OpenCV camera axes)}
                 for NAME in front, left_shoulder, right_shoulder, wrist},
     "gripper_open": float64 (1,) in [0, 1] (1 = fully open),
     "gripper_pose": float64 (4, 4) gripper (tool centre point) to world,
     "instruction":  Text, e.g. "put the yellow block on the target"}

World frame = the robot base: +x towards the table, +y left, +z up (docs/conventions.md).

**Action** (a :class:`gymnasium.spaces.Dict`, one keyframe, :class:`abm.types.KeyframeAction`)::

    {"position":         float64 (3,) tool-centre-point target in the world frame, metres, inside the
                                      policy's workspace cube (abm.geometry.Workspace),
     "quaternion":       float64 (4,) target orientation (x, y, z, w), normalised by the env
                                      (a zero quaternion is read as the identity),
     "gripper_open":     Discrete(2)  1 = open at the keyframe, 0 = closed,
     "ignore_collision": Discrete(2)  1 = move in a straight line ignoring collisions}

``step`` also takes a :class:`~abm.types.KeyframeAction` itself. :func:`to_action` and :func:`from_action` convert
between the two, :func:`to_observation` turns an observation back into :class:`~abm.types.Observation` (what
:meth:`abm.policy.KeyframePolicy.act` takes).

**Reward and ends**: reward 1.0 on the step that solves the task (``terminated``), else 0.0; ``truncated`` once
``max_steps`` keyframes are spent without success. ``info``: ``success``, ``motion`` (the keyframe's motion
status: reached, unreachable, blocked, collided), ``step``, ``task``, ``split``, ``scene_seed``, ``object_names``
(segmentation index -> object name, which the oracle grounder needs) and ``target_names``.

**Seeds**: ``reset(seed=k)`` builds the benchmark's scene of seed ``k`` (the seed ``abm eval`` and the experts use:
``reset(seed=k)`` twice gives the same scene); ``reset()`` without a seed draws the next scene seed from the env's
random generator; ``options={"scene_seed": k}`` picks the scene without reseeding.
"""

from __future__ import annotations

import string
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from abm.configuration import CAMERA_RESOLUTION
from abm.geometry import Workspace
from abm.sim.env import DEFAULT_MAX_STEPS, TaskEnv
from abm.sim.scene import CAMERA_NAMES
from abm.types import CameraFrame, KeyframeAction, Observation

INSTRUCTION_CHARSET = string.ascii_letters + string.digits + " _-',.?!:;()/&"
"""Characters an instruction of the Text space may hold."""
MAX_INSTRUCTION_LENGTH = 256
MAX_OBJECTS = 255
"""Upper bound of the segmentation's object indices."""
MAX_DEPTH = 100.0
"""Upper bound of the depth images, metres (farther readings are clipped to it)."""
MAX_COORDINATE = 100.0
"""Bound of the calibration matrices' and the gripper pose's entries (metres for translations)."""
MAX_PIXELS = 1e6
"""Bound of the intrinsics' entries, pixels."""
CACHED_SCENES = 4
"""Scenes kept built, so resetting to a recent seed does not compile the simulator again."""

Obs = dict[str, Any]
Act = dict[str, Any]


def observation_space(resolution: int, camera_names: Sequence[str] = CAMERA_NAMES) -> spaces.Dict:
    """The observation space (module docstring) for square cameras of ``resolution`` pixels."""
    r = int(resolution)
    camera = spaces.Dict({
        "rgb": spaces.Box(0, 255, (r, r, 3), np.uint8),
        "depth": spaces.Box(0.0, MAX_DEPTH, (r, r), np.float32),
        "segmentation": spaces.Box(-1, MAX_OBJECTS, (r, r), np.int32),
        "intrinsics": spaces.Box(-MAX_PIXELS, MAX_PIXELS, (3, 3), np.float64),
        "extrinsics": spaces.Box(-MAX_COORDINATE, MAX_COORDINATE, (4, 4), np.float64),
    })
    return spaces.Dict({
        "cameras": spaces.Dict({name: camera for name in camera_names}),
        "gripper_open": spaces.Box(0.0, 1.0, (1,), np.float64),
        "gripper_pose": spaces.Box(-MAX_COORDINATE, MAX_COORDINATE, (4, 4), np.float64),
        "instruction": spaces.Text(MAX_INSTRUCTION_LENGTH, min_length=1, charset=INSTRUCTION_CHARSET),
    })


def action_space(workspace: Workspace | None = None) -> spaces.Dict:
    """The keyframe action space (module docstring); positions inside ``workspace`` (default: the policy's)."""
    workspace = workspace or Workspace()
    return spaces.Dict({
        "position": spaces.Box(workspace.lower, workspace.upper, (3,), np.float64),
        "quaternion": spaces.Box(-1.0, 1.0, (4,), np.float64),
        "gripper_open": spaces.Discrete(2),
        "ignore_collision": spaces.Discrete(2),
    })


def from_action(action: KeyframeAction) -> Act:
    """A :class:`KeyframeAction` as an action of :func:`action_space` (position m, quaternion x y z w)."""
    return {"position": np.asarray(action.position, np.float64).copy(),
            "quaternion": np.asarray(action.quaternion, np.float64).copy(),
            "gripper_open": int(action.gripper_open), "ignore_collision": int(action.ignore_collision)}


def to_action(action: Mapping[str, Any] | KeyframeAction) -> KeyframeAction:
    """An action of :func:`action_space` (or a :class:`KeyframeAction`, returned as is) as a :class:`KeyframeAction`.

    Raises:
        ValueError: a key is missing, or a value has the wrong shape or is not finite.
    """
    if isinstance(action, KeyframeAction):
        return action
    missing = {"position", "quaternion", "gripper_open", "ignore_collision"} - set(action)
    if missing:
        raise ValueError(f"the action lacks {sorted(missing)}; give position (3,), quaternion (4,), gripper_open, "
                         "ignore_collision (abm.gym action space)")
    quaternion = np.asarray(action["quaternion"], np.float64).reshape(-1)
    if quaternion.shape == (4,) and np.all(np.isfinite(quaternion)) and np.linalg.norm(quaternion) < 1e-6:
        quaternion = np.array([0.0, 0.0, 0.0, 1.0])
    return KeyframeAction(np.asarray(action["position"], np.float64).reshape(-1), quaternion,
                          bool(int(np.asarray(action["gripper_open"]).reshape(-1)[0])),
                          bool(int(np.asarray(action["ignore_collision"]).reshape(-1)[0])))


def from_observation(obs: Observation, instruction: str) -> Obs:
    """An :class:`Observation` and its instruction as an observation of :func:`observation_space`."""
    cameras: dict[str, dict[str, NDArray[Any]]] = {}
    for name, frame in obs.cameras.items():
        seg = frame.segmentation if frame.segmentation is not None else np.full(frame.depth.shape, -1)
        depth = np.nan_to_num(np.asarray(frame.depth, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        cameras[name] = {"rgb": np.array(frame.rgb, np.uint8), "depth": np.clip(depth, 0.0, MAX_DEPTH),
                         "segmentation": np.array(seg, np.int32), "intrinsics": np.array(frame.intrinsics, np.float64),
                         "extrinsics": np.array(frame.extrinsics, np.float64)}
    return {"cameras": cameras, "gripper_open": np.array([obs.gripper_open], np.float64),
            "gripper_pose": np.array(obs.gripper_pose, np.float64), "instruction": str(instruction)}


def to_observation(obs: Mapping[str, Any], step: int = 0) -> Observation:
    """An observation of :func:`observation_space` as an :class:`Observation` (cameras, gripper state)."""
    cameras = {name: CameraFrame(np.asarray(c["rgb"], np.uint8), np.asarray(c["depth"], np.float32),
                                 np.asarray(c["intrinsics"], np.float64), np.asarray(c["extrinsics"], np.float64),
                                 np.asarray(c["segmentation"], np.int32))
               for name, c in obs["cameras"].items()}
    return Observation(cameras, float(np.asarray(obs["gripper_open"]).reshape(-1)[0]),
                       np.asarray(obs["gripper_pose"], np.float64), step)


class AbmTaskEnv(gymnasium.Env[Obs, Act]):
    """One task and split of ABM-Bench (module docstring for the spaces, rewards and seeds).

    Args:
        task: a task name (``abm tasks`` lists them).
        split: ``"seen"``, ``"unseen"`` or ``"compositional"`` (the splits the task has).
        resolution: camera image side in pixels (the benchmark's is 128).
        max_steps: keyframes before an episode is truncated.
        camera_names: the cameras rendered (default all four).
        render_mode: ``None`` or ``"rgb_array"`` (the front camera's image, ``(R, R, 3)`` uint8).
        splits_path: a replacement split file (default the built-in one).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, task: str, split: str = "seen", resolution: int = CAMERA_RESOLUTION,
                 max_steps: int = DEFAULT_MAX_STEPS, camera_names: Sequence[str] = CAMERA_NAMES,
                 render_mode: str | None = None, splits_path: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} is not supported; use None or 'rgb_array'")
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        self.task, self.split = task, split
        self.resolution, self.max_steps = int(resolution), int(max_steps)
        self.camera_names = tuple(camera_names)
        self.render_mode = render_mode
        self.splits_path = splits_path
        self.observation_space = observation_space(self.resolution, self.camera_names)
        self.action_space = action_space()
        self.env: TaskEnv | None = None
        self._scenes: dict[int, TaskEnv] = {}
        self._last: Obs | None = None
        self._env(0)  # fail now on an unknown task or split (no simulator is built yet)

    def _env(self, scene_seed: int) -> TaskEnv:
        """The :class:`TaskEnv` of ``scene_seed``, built or taken from the :data:`CACHED_SCENES` most recent."""
        env = self._scenes.pop(scene_seed, None)
        if env is None:
            env = TaskEnv(self.task, self.split, scene_seed, self.resolution, max_steps=self.max_steps,
                          splits_path=self.splits_path, camera_names=self.camera_names)
        self._scenes[scene_seed] = env  # the most recent last
        while len(self._scenes) > CACHED_SCENES:
            self._scenes.pop(next(iter(self._scenes))).close()
        self.env = env
        return env

    def _info(self, env: TaskEnv, success: bool = False, motion: str = "") -> dict[str, Any]:
        return {"success": bool(success), "motion": motion, "step": env.steps, "task": self.task, "split": self.split,
                "scene_seed": env.seed, "object_names": dict(env.object_names), "target_names": env.target_names}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Obs, dict[str, Any]]:
        """Build (or reset) a scene and return its first observation and info.

        Args:
            seed: the scene seed (and the seed of the env's generator); ``None`` draws the next scene seed.
            options: ``{"scene_seed": k}`` picks the scene without reseeding the generator.
        """
        super().reset(seed=seed)
        options = options or {}
        if "scene_seed" in options:
            scene_seed = int(options["scene_seed"])
        elif seed is not None:
            scene_seed = int(seed)
        else:
            scene_seed = int(self.np_random.integers(0, 2**31 - 1))
        if scene_seed < 0:
            raise ValueError(f"the scene seed must be non-negative, got {scene_seed}")
        env = self._env(scene_seed)
        obs = from_observation(env.reset(), env.instruction)
        self._last = obs
        return obs, self._info(env)

    def step(self, action: Act | KeyframeAction) -> tuple[Obs, float, bool, bool, dict[str, Any]]:
        """Execute one keyframe (a :func:`action_space` dict or a :class:`KeyframeAction`)."""
        if self.env is None or self.env.sim is None:
            raise RuntimeError("call reset() before step()")
        env = self.env
        observation, success, info = env.step(to_action(action))
        assert observation is not None  # rendered (render=True)
        obs = from_observation(observation, env.instruction)
        self._last = obs
        truncated = not success and env.steps >= self.max_steps
        return obs, 1.0 if success else 0.0, bool(success), truncated, self._info(env, success, info["motion"].status)

    def render(self) -> NDArray[np.uint8] | None:
        """The front camera's last image (``"rgb_array"``), or ``None`` without a render mode."""
        if self.render_mode is None or self._last is None:
            return None
        name = "front" if "front" in self._last["cameras"] else next(iter(self._last["cameras"]))
        return np.array(self._last["cameras"][name]["rgb"], np.uint8)

    def expert_actions(self) -> Iterator[KeyframeAction]:
        """The task's scripted expert for the current scene: a generator of :class:`KeyframeAction` that reads the
        simulator between keyframes, so step each one before asking for the next."""
        if self.env is None or self.env.sim is None:
            raise RuntimeError("call reset() before expert_actions()")
        return self.env.task.expert(self.env.sim, self.env.instance)

    def close(self) -> None:
        """Free the simulators (closing twice is fine)."""
        for env in self._scenes.values():
            env.close()
        self._scenes.clear()
        self.env = None
