"""Scene description and MJCF assembly: table, Franka Panda, cameras, lights and task objects.

World frame = robot-base frame (docs/conventions.md): the Panda's base is at the origin, +x points over
the table, the table top is the plane z = 0. The scene is assembled with :class:`mujoco.MjSpec`
from the Panda files of ``dm-robotics-panda`` and the objects of :mod:`abm.sim.catalog`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from abm.sim.assets import panda_dir
from abm.sim.catalog import catalog_entry, object_geometry, object_spec

if TYPE_CHECKING:
    import mujoco

ARM_JOINTS: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
HAND_PREFIX = "hand_"
FINGER_JOINTS: tuple[str, ...] = ("hand_panda_finger_joint1", "hand_panda_finger_joint2")
GRIPPER_ACTUATOR = "hand_panda_hand_actuator"
# A comfortable configuration: hand pointing down above the table, fingers along world y.
HOME_QPOS: tuple[float, ...] = (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785)
TCP_SITE = "hand_TCP"
HAND_BODY = "hand_panda_hand"
# Joint position servo gains (N m / rad and N m s / rad).
ARM_KP = (600.0, 600.0, 500.0, 500.0, 400.0, 300.0, 300.0)
ARM_KV = (60.0, 60.0, 50.0, 50.0, 40.0, 30.0, 30.0)
TABLE_HALF = (0.65, 0.75, 0.025)
TABLE_CENTER_X = 0.45
OBJECT_PREFIX = "obj{}_"
PHYSICS_TIMESTEP = 0.002  # s


@dataclass
class PlacedObject:
    """One object of a scene, resting on the table (or fixed to it).

    Attributes:
        name: canonical catalog name.
        x, y: position of the object's body origin on the table (m, world frame).
        yaw: rotation about world +z (rad).
        z: height of the body origin; ``None`` = resting on the table top.
    """

    name: str
    x: float
    y: float
    yaw: float = 0.0
    z: float | None = None

    def position(self) -> np.ndarray:
        """``(3,)`` body origin in the world; resting objects are lifted by their collision box."""
        z = self.z if self.z is not None else -object_geometry(self.name).lower[2] + 1e-4
        return np.array([self.x, self.y, z])


@dataclass
class SceneSpec:
    """Everything needed to build one episode's scene; object ``i`` has segmentation id ``i``.

    Attributes:
        objects: the task objects (target, containers, distractors).
        robot_qpos: initial arm joint angles ``(7,)`` in radians.
        info: task-specific data (e.g. goal slot), kept JSON-friendly.
    """

    objects: list[PlacedObject]
    robot_qpos: tuple[float, ...] = HOME_QPOS
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def object_names(self) -> dict[int, str]:
        return {i: o.name for i, o in enumerate(self.objects)}

    def index(self, name: str) -> int:
        for i, obj in enumerate(self.objects):
            if obj.name == name:
                return i
        raise KeyError(f"object {name!r} is not in the scene; objects: {[o.name for o in self.objects]}")


@dataclass(frozen=True)
class CameraSpec:
    """A fixed (or hand-mounted) camera.

    Attributes:
        name: camera name in observations.
        position: ``(3,)`` eye position (world, or hand frame when ``on_hand``), m.
        target: ``(3,)`` point looked at, same frame.
        up: approximate up direction, same frame.
        fovy: vertical field of view in degrees.
        on_hand: mounted on the Panda hand.
    """

    name: str
    position: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fovy: float = 45.0
    on_hand: bool = False


CAMERAS: tuple[CameraSpec, ...] = (
    CameraSpec("front", (1.35, 0.0, 0.75), (0.45, 0.0, 0.05), fovy=42.0),
    CameraSpec("left_shoulder", (0.05, 0.55, 0.8), (0.55, 0.0, 0.0), fovy=50.0),
    CameraSpec("right_shoulder", (0.05, -0.55, 0.8), (0.55, 0.0, 0.0), fovy=50.0),
    # Hand frame: +z points from the hand towards the fingertips, fingers slide along +-y.
    CameraSpec("wrist", (0.07, 0.0, 0.02), (0.0, 0.0, 0.2), up=(1.0, 0.0, 0.0), fovy=70.0, on_hand=True),
)
CAMERA_NAMES: tuple[str, ...] = tuple(c.name for c in CAMERAS)


def lookat_quat(position: Sequence[float], target: Sequence[float], up: Sequence[float]) -> np.ndarray:
    """MuJoCo camera quaternion ``(w, x, y, z)``: camera looks along its -z with +y up."""
    forward = np.asarray(target, float) - np.asarray(position, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, float))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    rot = np.stack([right, cam_up, -forward], axis=1)
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return np.array([w, x, y, z])


def _yaw_quat(yaw: float) -> list[float]:
    return [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]


def robot_spec(with_actuators: bool = True) -> mujoco.MjSpec:
    """Panda arm + hand as an :class:`mujoco.MjSpec` (base at the world origin)."""
    import mujoco

    folder = panda_dir()
    arm = mujoco.MjSpec.from_file(str(folder / "panda.xml"))
    hand = mujoco.MjSpec.from_file(str(folder / "panda_hand.xml"))
    for s in (arm, hand):
        for mesh in s.meshes:
            mesh.file = str(folder / mesh.file)
        for tex in s.textures:
            tex.file = str(folder / tex.file)
    for sensor in list(arm.sensors):
        arm.delete(sensor)
    hand.delete(hand.site("wrist_site"))
    # The Franka hand sits at -45 degrees about the flange axis.
    frame = arm.body("panda_link8").add_frame(quat=[np.cos(-np.pi / 8), 0, 0, np.sin(-np.pi / 8)])
    frame.attach_body(hand.body("panda_hand"), HAND_PREFIX, "")
    arm.compiler.degree = False
    for name, kp, kv in zip(ARM_JOINTS, ARM_KP, ARM_KV, strict=True):
        joint = arm.joint(name)
        joint.armature = 0.1
        if with_actuators:
            act = arm.add_actuator(name=f"{name}_servo", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm[0] = kp
            act.biasprm[0:3] = [0.0, -kp, -kv]
            act.ctrlrange = list(joint.range)
            act.ctrllimited = True
    # Finger pads: grippy boxes.
    for side in ("left", "right"):
        geom = arm.geom(f"{HAND_PREFIX}panda_{side}finger_collision")
        geom.friction = [1.5, 0.02, 0.002]
        geom.condim = 4
        geom.solref = [0.004, 1.0]
    if not with_actuators:
        for act in list(arm.actuators):
            arm.delete(act)
    return arm


def build_spec(scene: SceneSpec, cameras: tuple[CameraSpec, ...] = CAMERAS) -> mujoco.MjSpec:
    """Assemble the full scene (robot, table, cameras, objects) as an :class:`mujoco.MjSpec`."""
    import mujoco

    spec = robot_spec(with_actuators=True)
    spec.modelname = "abm_bench"
    spec.option.timestep = PHYSICS_TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.noslip_iterations = 3
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.map.znear = 0.01
    spec.visual.map.zfar = 10.0
    spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
    spec.visual.headlight.diffuse = [0.5, 0.5, 0.5]
    spec.visual.headlight.specular = [0.1, 0.1, 0.1]
    spec.stat.extent = 2.0
    spec.stat.center = [0.4, 0.0, 0.2]
    world = spec.worldbody
    world.add_light(pos=[0.6, 0.0, 2.0], dir=[0, 0, -1], diffuse=[0.5, 0.5, 0.5], castshadow=False)
    # Table (top at z = 0), floor and a back wall for a bounded depth background.
    spec.add_texture(name="floor_grid", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=[0.35, 0.35, 0.38],
                     rgb2=[0.3, 0.3, 0.33], width=256, height=256)
    spec.add_material(name="floor_mat", textures=["", "floor_grid"], texrepeat=[8, 8])
    floor = world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1],
                           pos=[0, 0, -0.75], material="floor_mat")
    floor.group = 0
    table = world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(TABLE_HALF),
                           pos=[TABLE_CENTER_X, 0, -TABLE_HALF[2]], rgba=[0.72, 0.6, 0.46, 1.0])
    table.friction = [1.0, 0.01, 0.001]
    for cam in cameras:
        parent = spec.body(HAND_BODY) if cam.on_hand else world
        parent.add_camera(name=cam.name, pos=list(cam.position),
                          quat=lookat_quat(cam.position, cam.target, cam.up).tolist(), fovy=cam.fovy)
    for i, obj in enumerate(scene.objects):
        entry = catalog_entry(obj.name)
        child = object_spec(obj.name)
        frame = world.add_frame(pos=obj.position().tolist(), quat=_yaw_quat(obj.yaw))
        body = frame.attach_body(child.body("root"), OBJECT_PREFIX.format(i), "")
        if entry.movable:
            body.add_freejoint(name=f"{OBJECT_PREFIX.format(i)}free")
    return spec
