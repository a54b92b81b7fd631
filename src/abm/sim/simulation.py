"""One running scene: MuJoCo model + data, cameras, robot controller and object bookkeeping."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from abm.sim.arm_control import STOPPED, MotionResult, RobotController
from abm.sim.cameras import CameraRig
from abm.sim.scene import CAMERA_NAMES, OBJECT_PREFIX, SceneSpec, build_spec
from abm.types import KeyframeAction, Observation

SETTLE_SECONDS = 0.3


class Simulation:
    """A built scene ready to step, render and control.

    Args:
        scene: what to build.
        resolution: camera image size (square), pixels.
        camera_names: cameras to render (subset of :data:`abm.sim.scene.CAMERA_NAMES`).
        segmentation: render each camera's segmentation (``False``: observations without it, one draw less per
            camera; see :class:`abm.sim.cameras.CameraRig`).
        reuse: an earlier simulation of the same scene (``scene``, ``resolution`` and ``camera_names`` equal, see
            :meth:`same_scene`; with or without segmentation) whose compiled model and camera renderer this one
            takes over instead of compiling and uploading them again (~0.2 + ~0.45 CPU s at 128²); ``reuse`` is
            closed.
            Everything that changes while stepping (the ``MjData``, the arm's controller and IK) is made anew,
            so the result steps and renders exactly as a fresh build. ``None`` or another scene: a fresh build.
            The first observation of ``reuse`` is taken over too (:meth:`first_observation`).
    """

    def __init__(self, scene: SceneSpec, resolution: int = 128,
                 camera_names: Sequence[str] = CAMERA_NAMES, segmentation: bool = True,
                 reuse: Simulation | None = None) -> None:
        import mujoco

        self._mujoco = mujoco
        if resolution < 8:
            raise ValueError(f"resolution must be at least 8 pixels, got {resolution}")
        self.scene = scene
        self.resolution = int(resolution)
        self.camera_names = list(camera_names)
        self.segmentation = bool(segmentation)
        self._cameras: CameraRig | None = None
        self._first: Observation | None = None  # see first_observation
        self.model: mujoco.MjModel
        if reuse is not None and reuse.same_scene(self):
            self.model, self._cameras, self._first = reuse.model, reuse._cameras, reuse._first
            reuse._cameras = None  # now this simulation's: closing ``reuse`` must not free it
            if self._cameras is not None:  # the rig reads the flag at every render
                self._cameras.segmentation = self.segmentation
        else:
            spec = build_spec(scene)
            spec.visual.global_.offwidth = max(640, self.resolution)
            spec.visual.global_.offheight = max(480, self.resolution)
            self.model = spec.compile()
        if reuse is not None:
            reuse.close()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.object_root_bodies = [m.body(f"{OBJECT_PREFIX.format(i)}root").id for i in range(len(scene.objects))]
        body_to_object = np.full(m.nbody, -1, np.int32)
        for i, root in enumerate(self.object_root_bodies):
            body_to_object[m.body_rootid == root] = i
        self.geom_to_object = body_to_object[m.geom_bodyid]
        robot_root = m.body("panda_link0").id
        robot_geoms = m.body_rootid[m.geom_bodyid] == robot_root
        names = [m.geom(g).name for g in range(m.ngeom)]
        finger_geoms = np.array(["finger_collision" in n for n in names])
        for g in range(m.ngeom):
            if not names[g] and self.geom_to_object[g] >= 0:
                names[g] = scene.objects[self.geom_to_object[g]].name
        self.robot = RobotController(m, self.data, robot_geoms, finger_geoms, self.geom_to_object, names)
        self.step_count = 0
        self.reset()

    def same_scene(self, other: Simulation) -> bool:
        """Whether ``other`` is built from the same scene, cameras and resolution as this one (so it may take over
        this one's model and renderer, see ``reuse``; the segmentation is a choice of each render)."""
        return (self.scene == other.scene and self.resolution == other.resolution
                and self.camera_names == other.camera_names)

    # --- lifecycle ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scene's initial state: objects at their poses, arm at the start posture."""
        self._mujoco.mj_resetData(self.model, self.data)
        self.robot.set_arm(np.asarray(self.scene.robot_qpos), gripper_open=True)
        self.step_seconds(SETTLE_SECONDS)
        self.step_count = 0

    def close(self) -> None:
        if self._cameras is not None:
            self._cameras.close()
            self._cameras = None

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def step_seconds(self, seconds: float) -> None:
        """Advance physics with the current controls."""
        for _ in range(max(1, int(round(seconds / self.model.opt.timestep)))):
            self._mujoco.mj_step(self.model, self.data)

    # --- perception --------------------------------------------------------------------------
    @property
    def cameras(self) -> CameraRig:
        if self._cameras is None:
            self._cameras = CameraRig(self.model, self.camera_names, self.resolution, self.resolution,
                                      self.geom_to_object, self.segmentation)
        return self._cameras

    def observe(self) -> Observation:
        """Render all cameras and read the gripper state at the current time."""
        return Observation(cameras=self.cameras.render(self.data), gripper_open=self.robot.gripper_opening(),
                           gripper_pose=self.robot.tcp_pose(), step=self.step_count)

    def first_observation(self) -> Observation:
        """:meth:`observe` of the state the build's reset left, drawn once per scene and process.

        Call it right after the simulation was made (nothing stepped, nothing moved since). The scene's initial
        state is the same in every simulation of the scene (a fresh ``MjData``, the same reset), so the first
        observation is too: it is kept with the compiled model and renderer and handed over with them
        (``reuse``), and a later simulation of the scene, e.g. another model's rollout in an evaluation, gets a
        copy instead of drawing its cameras again (~0.1 CPU s at 128²). A kept observation without segmentation
        is drawn again for a simulation that renders segmentation; one with segmentation is given without it to
        a simulation that renders none, as :meth:`observe` would (its colour and depth are those of a draw
        without segmentation: :class:`abm.sim.cameras.CameraRig`)."""
        if self._first is None or (self.segmentation and not _has_segmentation(self._first)):
            self._first = self.observe()
        return _copy_observation(self._first, self.segmentation)

    # --- objects -----------------------------------------------------------------------------
    def object_index(self, name: str) -> int:
        return self.scene.index(name)

    def object_pose(self, obj: int | str) -> np.ndarray:
        """``(4, 4)`` body-to-world pose of a scene object (by id or canonical name)."""
        i = self.object_index(obj) if isinstance(obj, str) else int(obj)
        body = self.object_root_bodies[i]
        out = np.eye(4)
        out[:3, :3] = self.data.xmat[body].reshape(3, 3)
        out[:3, 3] = self.data.xpos[body]
        return out

    def held_objects(self) -> set[int]:
        return self.robot.held_objects()

    # --- control -----------------------------------------------------------------------------
    def execute(self, action: KeyframeAction) -> MotionResult:
        """Move to the keyframe pose, then open/close the gripper (not when unreachable or blocked)."""
        result = self.robot.move_to(action.matrix, action.ignore_collision)
        if result.status not in STOPPED:
            self.robot.actuate_gripper(action.gripper_open)
        self.step_count += 1
        return result


def _has_segmentation(observation: Observation) -> bool:
    return all(frame.segmentation is not None for frame in observation.cameras.values())


def _copy_observation(observation: Observation, segmentation: bool) -> Observation:
    """A copy of ``observation`` whose arrays are its own (the caller may change them), with the cameras'
    segmentation only when ``segmentation``."""
    copied = copy.deepcopy(observation)
    if not segmentation:
        for frame in copied.cameras.values():
            frame.segmentation = None
    return copied
