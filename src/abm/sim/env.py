"""Environment API for policies and scripted experts.

Example::

    env = make_env("place_food", split="seen", seed=3, resolution=128)
    obs = env.reset()
    while True:
        obs, success, info = env.step(policy(obs))
        if info["done"]:
            break
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Literal, overload

import mujoco

from abm.geometry.rotations import canonical_gripper_quat, matrix_to_quat
from abm.sim.arm_control import FLIP_Z, STOPPED
from abm.sim.recorder import DenseRecorder
from abm.sim.scene import CAMERA_NAMES
from abm.sim.simulation import Simulation
from abm.sim.splits import load_splits
from abm.sim.tasks import Task, TaskInstance, get_task
from abm.types import TASK_VERSION_KEY, Episode, KeyframeAction, Observation, task_data_version

DEFAULT_MAX_STEPS = 25
Policy = Callable[[Observation], KeyframeAction]


class TaskEnv:
    """One task episode in simulation, stepped one keyframe at a time.

    Args:
        task: a task name or :class:`Task` instance.
        split: ``"seen"`` / ``"unseen"`` (or any split the split file defines).
        seed: scene seed (same seed -> same scene).
        resolution: square camera resolution in pixels.
        max_steps: keyframes before an episode ends unsuccessfully.
        splits_path: optional replacement split file.
        camera_names: cameras rendered into observations.
        segmentation: render the cameras' segmentation (``False``: the observations have none, for policies
            that never read it; one draw less per camera).
        reuse: an earlier environment whose simulation this one takes over at its first :meth:`reset` when it is
            the same scene (its compiled model and camera renderer; the state is made anew, so the episode is the
            one a fresh build gives: :class:`abm.sim.simulation.Simulation`'s ``reuse``); ``reuse`` is closed then.
    """

    def __init__(self, task: str | Task, split: str = "seen", seed: int = 0, resolution: int = 128,
                 max_steps: int = DEFAULT_MAX_STEPS, splits_path: str | Path | None = None,
                 camera_names: Sequence[str] = CAMERA_NAMES, segmentation: bool = True,
                 reuse: TaskEnv | None = None) -> None:
        self.task = task if isinstance(task, Task) else get_task(task, load_splits(splits_path))
        self.split, self.seed = split, int(seed)
        self.resolution, self.max_steps = int(resolution), int(max_steps)
        self.camera_names = tuple(camera_names)
        self.segmentation = bool(segmentation)
        self.instance: TaskInstance = self.task.sample(self.seed, split)
        self.sim: Simulation | None = None
        self.steps = 0
        self._reuse = reuse

    @property
    def instruction(self) -> str:
        return self.instance.instruction

    @property
    def object_names(self) -> dict[int, str]:
        return self.instance.scene.object_names

    @property
    def target_names(self) -> list[str]:
        return list(self.instance.target_names)

    def reset(self) -> Observation:
        """Build (first call) or reset the scene and return the first observation (at the first call the
        scene's kept one when this environment took over an earlier one's simulation:
        :meth:`abm.sim.simulation.Simulation.first_observation`)."""
        self.steps = 0
        if self.sim is None:
            earlier, self._reuse = self._reuse, None
            self.sim = Simulation(self.instance.scene, self.resolution, self.camera_names, self.segmentation,
                                  reuse=earlier.sim if earlier is not None else None)
            if earlier is not None:
                earlier.close()
            return self.sim.first_observation()
        self.sim.reset()
        return self.sim.observe()

    def _require_sim(self) -> Simulation:
        if self.sim is None:
            raise RuntimeError("call env.reset() before env.step() / env.success()")
        return self.sim

    def success(self) -> bool:
        return bool(self.task.success(self._require_sim(), self.instance))

    @overload
    def step(self, action: KeyframeAction, render: Literal[True] = True) -> tuple[Observation, bool, dict[str, Any]]:
        ...

    @overload
    def step(self, action: KeyframeAction, render: bool) -> tuple[Observation | None, bool, dict[str, Any]]:
        ...

    def step(self, action: KeyframeAction, render: bool = True
             ) -> tuple[Observation | None, bool, dict[str, Any]]:
        """Execute one keyframe.

        Returns:
            ``(observation, success, info)``; ``info`` holds ``"motion"`` (a
            :class:`abm.sim.arm_control.MotionResult`), ``"done"`` (success, or the step budget is spent)
            and ``"step"``. ``observation`` is ``None`` when ``render`` is false.
        """
        sim = self._require_sim()
        if not isinstance(action, KeyframeAction):
            raise TypeError(f"env.step needs a KeyframeAction, got {type(action).__name__}")
        motion = sim.execute(action)
        self.steps += 1
        success = self.success()
        done = success or self.steps >= self.max_steps
        obs = sim.observe() if render else None
        return obs, success, {"motion": motion, "done": done, "step": self.steps}

    def expert_actions(self) -> Iterator[KeyframeAction]:
        """The task's scripted expert for the current state (a generator of keyframes)."""
        return self.task.expert(self._require_sim(), self.instance)

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None
        if self._reuse is not None:
            self._reuse.close()
            self._reuse = None

    def __enter__(self) -> TaskEnv:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_env(task: str, split: str = "seen", seed: int = 0, resolution: int = 128, **kwargs: Any) -> TaskEnv:
    """Create a :class:`TaskEnv` (see its arguments)."""
    return TaskEnv(task, split, seed, resolution, **kwargs)


def _episode(env: TaskEnv, steps: list[tuple[Observation, KeyframeAction]], success: bool, extra: dict[str, Any]
             ) -> Episode:
    return Episode(task=env.task.name, variation=env.instance.variation, split=env.split,
                   instruction=env.instruction, object_names=env.object_names,
                   target_names=env.target_names, steps=steps, success=success, seed=env.seed,
                   metadata={"resolution": env.resolution, "mujoco": mujoco.__version__,
                             TASK_VERSION_KEY: task_data_version(env.task.name), **extra})


def executed_action(action: KeyframeAction, flipped: bool) -> KeyframeAction:
    """The keyframe the arm actually executed, in canonical form.

    When the controller had to fall back to the grasp turned 180 degrees about the gripper axis (see
    :meth:`PandaIK.solve_either`), that turn is applied and the result canonicalised with the label's
    symmetry: for the symmetric classes (2, 4, 0) it is the commanded label again, for symmetry 1 the
    executed orientation.
    """
    if not flipped:
        return action
    executed = action.matrix[:3, :3] @ FLIP_Z
    return dataclasses.replace(action, quaternion=canonical_gripper_quat(matrix_to_quat(executed), action.symmetry))


def run_expert(env: TaskEnv, record: bool = True, dense_fps: float | None = None) -> Episode:
    """Roll out the scripted expert; returns the episode of (observation, keyframe) pairs.

    The metadata holds each executed keyframe's motion status (``motions``), the wall time
    (``seconds``) and, for tasks that label them (:meth:`Task.keyframe_subgoal`, e.g. put_in_container),
    ``subgoals``: per executed keyframe the index into ``target_names`` of the object it works on.
    With ``dense_fps`` the whole motion is also recorded at that control rate (``episode.trajectory``,
    see :mod:`abm.sim.recorder`).
    """
    start = time.perf_counter()
    env.reset()
    sim = env._require_sim()
    recorder = DenseRecorder(sim, dense_fps) if dense_fps else None
    steps: list[tuple[Observation, KeyframeAction]] = []
    motions = []
    subgoals: list[int | None] = []
    for action in env.expert_actions():
        obs = (recorder.keyframe() if recorder else sim.observe()) if record else None
        motion = sim.execute(action)
        motions.append(motion.status)
        subgoals.append(env.task.keyframe_subgoal(action))
        if obs is not None:  # recording
            steps.append((obs, executed_action(action, motion.flipped)))
        if motion.status in STOPPED:
            break
    trajectory = recorder.detach() if recorder else None
    success = env.success()
    extra: dict[str, Any] = {"motions": motions, "seconds": round(time.perf_counter() - start, 3)}
    if any(g is not None for g in subgoals):
        extra["subgoals"] = subgoals
    episode = _episode(env, steps, success, extra)
    if trajectory is not None and record:
        episode.trajectory = trajectory
        episode.metadata["dense_fps"] = trajectory.fps
    return episode


def run_policy(env: TaskEnv, policy: Policy, max_steps: int | None = None) -> Episode:
    """Roll out ``policy`` (Observation -> KeyframeAction) until success or the step budget.

    The episode's metadata records each keyframe's motion status (``motions``), how far the TCP ended from
    the keyframe's pose (``stop_errors``, m; NaN when the arm did not move), whether the gripper held the object
    the task must hold (:meth:`abm.sim.tasks.Task.held_object`: the ring for insert_peg, the lid for close_jar,
    else the target) after each keyframe (``held``) and at any point (``held_target``), from which evaluation
    names the failure.
    """
    obs = env.reset()
    steps: list[tuple[Observation, KeyframeAction]] = []
    success = False
    motions, stop_errors, held_after = [], [], []
    carried = env.task.held_object(env.instance)
    budget = max_steps or env.max_steps
    for k in range(budget):
        action = policy(obs)
        steps.append((obs, action))
        _, success, info = env.step(action, render=False)
        motions.append(info["motion"].status)
        stop_errors.append(float(info["motion"].position_error))
        held_after.append(carried is not None and carried in env._require_sim().held_objects())
        if info["done"] or k == budget - 1:
            break
        obs = env._require_sim().observe()  # only when the policy acts on it (no draw after the last keyframe)
    return _episode(env, steps, success, {"motions": motions, "stop_errors": stop_errors, "held": held_after,
                                          "held_target": any(held_after)})
