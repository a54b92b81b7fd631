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

``step`` also takes a :class:`~abm.types.KeyframeAction` itself. Anything outside the space (a position outside the
Box, NaN or inf, a wrong shape or type, ``None``, a flag other than 0 or 1, a missing or unknown key) is refused with a
``ValueError`` naming the space and what was given, before the simulator or the arm's IK sees it
(:func:`check_action`). :func:`to_action` and :func:`from_action` convert between the two, :func:`to_observation`
turns an observation back into :class:`~abm.types.Observation` (what :meth:`abm.policy.KeyframePolicy.act` takes).

**Reward and ends**: reward 1.0 on the step that solves the task (``terminated``), else 0.0; ``truncated`` once
the episode's keyframes are spent without success: 25 (:data:`abm.sim.env.DEFAULT_MAX_STEPS`, the benchmark's budget,
what ``abm eval`` gives) by the ``TimeLimit`` that ``gymnasium.make`` adds from the registered spec's
``max_episode_steps``; ``gymnasium.make(id, max_episode_steps=N)`` changes it. An env built without ``gymnasium.make``
truncates itself only when given ``max_steps``. ``info``: ``success``, ``motion`` (the keyframe's motion
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


ACTION_KEYS = ("position", "quaternion", "gripper_open", "ignore_collision")
"""The keys of an action of :func:`action_space`."""


def _shown(value: object) -> str:
    """``value`` as the error messages quote it (shortened to 80 characters)."""
    if isinstance(value, np.ndarray):
        text = f"array({np.array2string(value, separator=', ', threshold=8)}, {value.dtype})"
    else:
        text = f"{value!r} ({type(value).__name__})"
    return text if len(text) <= 80 else text[:77] + "..."


def _outside(key: str, space: spaces.Space[Any], value: object, why: str) -> ValueError:
    return ValueError(f"abm.gym action: {key} = {_shown(value)} is outside the action space's {key} {space}: {why}")


def _box_value(key: str, box: spaces.Box, value: object) -> NDArray[np.float64]:
    """``value`` as a float64 array of ``box``, or the :class:`ValueError` that says why it is not one."""
    if value is None or isinstance(value, (str, bytes, Mapping)):
        raise _outside(key, box, value, f"expected an array of {box.shape[0]} numbers")
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as err:  # ragged nesting
        raise _outside(key, box, value, f"expected an array of {box.shape[0]} numbers") from err
    if array.dtype.kind not in "biuf":
        raise _outside(key, box, value, f"expected numbers, got elements of type {array.dtype}")
    if array.shape != box.shape:
        raise _outside(key, box, value, f"shape {array.shape}, expected {box.shape}")
    array = array.astype(np.float64)
    for i, (v, lo, hi) in enumerate(zip(array, box.low, box.high, strict=True)):
        if not np.isfinite(v):
            raise _outside(key, box, value, f"element {i} is {v}, not a finite number")
        if not lo <= v <= hi:
            raise _outside(key, box, value, f"element {i} is {v:.6g}, outside [{lo:.6g}, {hi:.6g}]")
    return array


def _flag_value(key: str, discrete: spaces.Discrete, value: object) -> int:
    """``value`` as an element of ``discrete`` (a Python int or bool, a numpy integer), or the :class:`ValueError`
    that says why it is not one."""
    if isinstance(value, np.ndarray) and value.shape == () and np.issubdtype(value.dtype, np.integer):
        value = value[()]
    if not isinstance(value, (int, np.integer)):
        raise _outside(key, discrete, value, "expected the integer 0 or 1")
    if value not in discrete:
        raise _outside(key, discrete, value, "expected 0 or 1")
    return int(value)


def check_action(action: object, space: spaces.Dict | None = None) -> Act:
    """``action`` as an element of ``space`` (default :func:`action_space`), checked before anything uses it.

    Takes a dict of the space or a :class:`KeyframeAction` (read with :func:`from_action`). Returns the dict with
    float64 arrays and ``int`` flags.

    Raises:
        ValueError: naming the space and what was given, for anything not in the space: a missing or unknown key,
            ``None``, a wrong type or shape, NaN or inf, a position outside the Box (the workspace cube), a
            quaternion element outside [-1, 1], a gripper_open or ignore_collision other than 0 or 1.
    """
    space = space or action_space()
    if isinstance(action, KeyframeAction):
        action = from_action(action)
    if not isinstance(action, Mapping):
        raise ValueError(f"abm.gym action: expected a dict with the keys {list(ACTION_KEYS)} (the action space "
                         f"{space}) or a KeyframeAction, got {_shown(action)}")
    missing = [k for k in ACTION_KEYS if k not in action]
    unknown = sorted(str(k) for k in action if k not in ACTION_KEYS)
    if missing or unknown:
        wrong = " and ".join([f"lacks {missing}"] * bool(missing) + [f"has unknown keys {unknown}"] * bool(unknown))
        raise ValueError(f"abm.gym action: the action {wrong}; give position (3,), quaternion (4,), gripper_open, "
                         f"ignore_collision (the action space {space})")
    checked: Act = {}
    for key in ACTION_KEYS:
        sub = space[key]
        if isinstance(sub, spaces.Box):
            checked[key] = _box_value(key, sub, action[key])
        else:
            assert isinstance(sub, spaces.Discrete)
            checked[key] = _flag_value(key, sub, action[key])
    return checked


def to_action(action: Mapping[str, Any] | KeyframeAction, space: spaces.Dict | None = None) -> KeyframeAction:
    """An action of ``space`` (default :func:`action_space`) as a :class:`KeyframeAction` (a KeyframeAction is
    checked and returned as is); a zero quaternion is read as the identity.

    Raises:
        ValueError: the action is not in the space (:func:`check_action`).
    """
    checked = check_action(action, space)
    if isinstance(action, KeyframeAction):
        return action
    quaternion = checked["quaternion"]
    if np.linalg.norm(quaternion) < 1e-6:
        quaternion = np.array([0.0, 0.0, 0.0, 1.0])
    return KeyframeAction(checked["position"], quaternion, bool(checked["gripper_open"]),
                          bool(checked["ignore_collision"]))


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
        max_steps: keyframes after which the env truncates an episode itself; ``None`` (the default): it does not,
            and the ``TimeLimit`` of ``gymnasium.make`` does (the spec's ``max_episode_steps``, 25, or
            ``max_episode_steps=N`` given to ``make``: one limit, so the spec and the episodes agree). Give it for an
            env built without ``gymnasium.make``; under ``make``, the shorter of the two ends the episode.
        camera_names: the cameras rendered (default all four).
        render_mode: ``None`` (the default: :meth:`render` returns ``None``) or ``"rgb_array"`` (:meth:`render`
            returns the front camera's last image, ``(R, R, 3)`` uint8).
        splits_path: a replacement split file (default the built-in one).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, task: str, split: str = "seen", resolution: int = CAMERA_RESOLUTION,
                 max_steps: int | None = None, camera_names: Sequence[str] = CAMERA_NAMES,
                 render_mode: str | None = None, splits_path: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} is not supported; use None or 'rgb_array'")
        if max_steps is not None and max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        self.task, self.split = task, split
        self.resolution = int(resolution)
        self.max_steps = None if max_steps is None else int(max_steps)
        self.camera_names = tuple(camera_names)
        self.render_mode = render_mode
        self.splits_path = splits_path
        self.observation_space = observation_space(self.resolution, self.camera_names)
        self._action_space = action_space()
        self.action_space = self._action_space
        self.env: TaskEnv | None = None
        self._scenes: dict[int, TaskEnv] = {}
        self._last: Obs | None = None
        self._env(0)  # fail now on an unknown task or split (no simulator is built yet)

    def _env(self, scene_seed: int) -> TaskEnv:
        """The :class:`TaskEnv` of ``scene_seed``, built or taken from the :data:`CACHED_SCENES` most recent."""
        env = self._scenes.pop(scene_seed, None)
        if env is None:
            env = TaskEnv(self.task, self.split, scene_seed, self.resolution,
                          max_steps=self.max_steps or DEFAULT_MAX_STEPS,  # (its "done" flag is not used here)
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
        """Execute one keyframe (a :func:`action_space` dict or a :class:`KeyframeAction`).

        Raises:
            ValueError: the action is not in the action space (:func:`check_action`); nothing is executed.
        """
        if self.env is None or self.env.sim is None:
            raise RuntimeError("call reset() before step()")
        keyframe = to_action(action, self._action_space)  # before the simulator or the IK sees it
        env = self.env
        observation, success, info = env.step(keyframe)
        assert observation is not None  # rendered (render=True)
        obs = from_observation(observation, env.instruction)
        self._last = obs
        truncated = not success and self.max_steps is not None and env.steps >= self.max_steps
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
