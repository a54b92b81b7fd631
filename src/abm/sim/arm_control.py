"""Panda control: inverse kinematics with mink and keyframe motion execution in physics.

A :class:`abm.types.KeyframeAction` is executed in three stages:

1. **IK** for the TCP target on a robot-only model (:class:`PandaIK`). If the target has no solution,
   the same grasp turned by 180 degrees about the gripper axis (equivalent for a parallel gripper) is
   tried; if neither solves, the result is ``"unreachable"`` and nothing moves.
2. **Path**: ``ignore_collision=True`` gives a straight Cartesian line (IK at waypoints every
   <= 1 cm / 5 degrees); otherwise a collision-avoiding path: up to a safe height, across, then down.
3. **Execution** in physics with joint position servos (gravity compensation comes from the bodies'
   ``gravcomp``), then the gripper opens or closes. Contacts of the arm with the scene during a
   collision-avoiding motion make the result ``"collided"``; a motion that ends more than 1 cm / 5 degrees
   from its target without such contacts (something stopped the arm or the held object) is ``"blocked"``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from abm.sim.scene import ARM_JOINTS, FINGER_JOINTS, GRIPPER_ACTUATOR, HOME_QPOS, TCP_SITE, robot_spec

if TYPE_CHECKING:
    import mujoco

MotionStatus = Literal["reached", "unreachable", "blocked", "collided"]
STOPPED: tuple[MotionStatus, ...] = ("unreachable", "blocked")
"""Statuses after which the gripper is not actuated and an expert demonstration ends."""
REACH_TOLERANCE = (0.01, 5.0)  # m, degrees: a motion ending farther from its target did not reach it

SAFE_HEIGHT = 0.25          # m, TCP height for collision-avoiding transfers
MAX_CART_STEP = 0.01        # m between Cartesian waypoints
MAX_ROT_STEP = np.radians(5.0)
JOINT_SPEED = 1.2           # rad/s, peak joint speed of the interpolation
CART_SPEED = 0.3            # m/s
SETTLE_TIME = 0.3           # s after each motion
GRIPPER_TIME = 0.6          # s to open/close
FINGER_MAX = 0.04           # m per finger
FLIP_Z = np.diag([-1.0, -1.0, 1.0])  # 180 degrees about the gripper (TCP z) axis


@dataclass
class MotionResult:
    """Outcome of executing one keyframe.

    Attributes:
        status: ``"reached"``; ``"unreachable"`` (no IK solution, or the straight path leaves the reachable
            space: the arm did not move); ``"blocked"`` (the arm moved but ended more than
            :data:`REACH_TOLERANCE` from the target, e.g. pressing into an object); or ``"collided"``.
        position_error: final TCP distance to the target, m (NaN if nothing moved).
        rotation_error_deg: final TCP angle to the target (either grasp flip), degrees.
        message: human-readable explanation.
        contacts: names of scene geoms the arm touched during a collision-avoiding motion.
        flipped: whether the 180-degree flipped grasp was used.
    """

    status: MotionStatus
    position_error: float = float("nan")
    rotation_error_deg: float = float("nan")
    message: str = ""
    contacts: list[str] = field(default_factory=list)
    flipped: bool = False

    @property
    def ok(self) -> bool:
        return self.status == "reached"


@functools.cache
def ik_model() -> mujoco.MjModel:
    """The robot-only model IK solves on, compiled once per process (every scene has the same robot; the
    model is only read: each :class:`PandaIK` has its own ``MjData``)."""
    return robot_spec(with_actuators=False).compile()


class PandaIK:
    """Inverse kinematics for the Panda TCP with mink (on a robot-only model).

    Args:
        position_tolerance: m.
        rotation_tolerance: rad.
        max_iterations: per solve.
    """

    def __init__(self, position_tolerance: float = 2e-4, rotation_tolerance: float = 2e-3,
                 max_iterations: int = 200) -> None:
        import mink

        self._mink = mink
        self.model = ik_model()
        self.configuration = mink.Configuration(self.model)
        self.frame_task = mink.FrameTask(TCP_SITE, "site", position_cost=1.0, orientation_cost=1.0,
                                         lm_damping=1e-3)
        self.posture_task = mink.PostureTask(self.model, cost=1e-3)
        self.limits = [mink.ConfigurationLimit(self.model, min_distance_from_limits=0.02)]
        self.position_tolerance = position_tolerance
        self.rotation_tolerance = rotation_tolerance
        self.max_iterations = max_iterations
        q = np.zeros(self.model.nq)
        q[:7] = HOME_QPOS
        self.posture_task.set_target(q)

    def forward(self, arm_q: np.ndarray) -> np.ndarray:
        """``(4, 4)`` TCP pose for arm joint angles ``(7,)``."""
        q = np.zeros(self.model.nq)
        q[:7] = arm_q
        self.configuration.update(q)
        return self.configuration.get_transform_frame_to_world(TCP_SITE, "site").as_matrix()

    def solve(self, target: np.ndarray, q_init: np.ndarray, max_iterations: int | None = None
              ) -> np.ndarray | None:
        """Arm joint angles ``(7,)`` placing the TCP at ``target`` (4x4), or ``None`` if none found."""
        mink = self._mink
        q = np.zeros(self.model.nq)
        q[:7] = q_init
        self.configuration.update(q)
        self.frame_task.set_target(mink.SE3.from_matrix(np.asarray(target, np.float64)))
        dt = 0.05
        iters = max_iterations or self.max_iterations
        for _ in range(iters):
            err = self.frame_task.compute_error(self.configuration)
            if np.linalg.norm(err[:3]) < self.position_tolerance and \
                    np.linalg.norm(err[3:]) < self.rotation_tolerance:
                return self.configuration.q[:7].copy()
            vel = mink.solve_ik(self.configuration, [self.frame_task, self.posture_task], dt,
                                solver="daqp", damping=1e-3, limits=self.limits)
            self.configuration.integrate_inplace(vel, dt)
        err = self.frame_task.compute_error(self.configuration)
        if np.linalg.norm(err[:3]) < 5 * self.position_tolerance and \
                np.linalg.norm(err[3:]) < 5 * self.rotation_tolerance:
            return self.configuration.q[:7].copy()
        return None

    def solve_either(self, target: np.ndarray, q_init: np.ndarray) -> tuple[np.ndarray | None, bool]:
        """Solve for ``target``; fall back to its 180-degree flip about the gripper axis.

        The commanded orientation is preferred so that the pose the arm reaches is the pose that
        was asked for (demonstration labels are canonical, see
        :func:`abm.geometry.canonical_gripper_matrix`). The local solver starts from ``q_init`` and
        then from :data:`HOME_QPOS`; only when the commanded pose fails from both is the flipped
        pose tried, so a policy's non-canonical prediction still executes.

        Returns:
            ``(q, flipped)``; ``q`` is ``None`` when neither pose is reachable.
        """
        target = np.asarray(target, np.float64)
        flipped = target.copy()
        flipped[:3, :3] = target[:3, :3] @ FLIP_Z
        for pose, is_flipped in ((target, False), (flipped, True)):
            for start in (np.asarray(q_init, np.float64), np.asarray(HOME_QPOS)):
                q = self.solve(pose, start)
                if q is not None:
                    return q, is_flipped
        return None, False


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Position (m) and rotation (deg) error between two TCP poses, allowing the gripper flip."""
    pos = float(np.linalg.norm(a[:3, 3] - b[:3, 3]))
    rots = [Rotation.from_matrix(a[:3, :3].T @ b[:3, :3] @ f).magnitude() for f in (np.eye(3), FLIP_Z)]
    return pos, float(np.degrees(min(rots)))


def cartesian_waypoints(start: np.ndarray, goal: np.ndarray) -> list[np.ndarray]:
    """TCP poses on the straight line from ``start`` to ``goal`` (4x4 each, excluding ``start``)."""
    dist = np.linalg.norm(goal[:3, 3] - start[:3, 3])
    angle = Rotation.from_matrix(start[:3, :3].T @ goal[:3, :3]).magnitude()
    n = max(1, int(np.ceil(max(dist / MAX_CART_STEP, angle / MAX_ROT_STEP))))
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([start[:3, :3], goal[:3, :3]])))
    out = []
    for t in np.linspace(0.0, 1.0, n + 1)[1:]:
        pose = np.eye(4)
        pose[:3, :3] = slerp([t]).as_matrix()[0]
        pose[:3, 3] = (1 - t) * start[:3, 3] + t * goal[:3, 3]
        out.append(pose)
    return out


class RobotController:
    """Executes keyframes on the Panda of a running simulation.

    Args:
        model, data: the full scene's :class:`mujoco.MjModel` / :class:`mujoco.MjData`.
        robot_geoms: ``(ngeom,)`` bool, geoms belonging to the robot.
        finger_geoms: ``(ngeom,)`` bool, the finger pad geoms.
        geom_to_object: ``(ngeom,)`` int32 object id of each geom (-1 = none).
        geom_names: name for each geom (for messages).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, robot_geoms: np.ndarray,
                 finger_geoms: np.ndarray, geom_to_object: np.ndarray, geom_names: list[str]) -> None:
        import mujoco

        self._mujoco = mujoco
        self.model, self.data = model, data
        self.ik = PandaIK()
        self.arm_qpos_adr = np.array([model.jnt_qposadr[model.joint(n).id] for n in ARM_JOINTS])
        self.finger_qpos_adr = np.array([model.jnt_qposadr[model.joint(n).id] for n in FINGER_JOINTS])
        self.arm_act = np.array([model.actuator(f"{n}_servo").id for n in ARM_JOINTS])
        self.gripper_act = model.actuator(GRIPPER_ACTUATOR).id
        self.tcp_site = model.site(TCP_SITE).id
        self.robot_geoms = robot_geoms
        self.finger_geoms = finger_geoms
        self.geom_to_object = geom_to_object
        self.geom_names = geom_names

    # --- state -------------------------------------------------------------------------------
    @property
    def arm_q(self) -> np.ndarray:
        q: np.ndarray = self.data.qpos[self.arm_qpos_adr].copy()
        return q

    def tcp_pose(self) -> np.ndarray:
        """``(4, 4)`` current TCP-to-world transform."""
        out = np.eye(4)
        out[:3, :3] = self.data.site_xmat[self.tcp_site].reshape(3, 3)
        out[:3, 3] = self.data.site_xpos[self.tcp_site]
        return out

    def gripper_opening(self) -> float:
        """Finger opening in ``[0, 1]`` (1 = fully open)."""
        width = float(self.data.qpos[self.finger_qpos_adr].sum())
        return float(np.clip(width / (2 * FINGER_MAX), 0.0, 1.0))

    def set_arm(self, q: np.ndarray, gripper_open: bool = True) -> None:
        """Teleport the arm (no physics) and hold it there: used at reset."""
        self.data.qpos[self.arm_qpos_adr] = q
        self.data.qvel[:] = 0.0
        self.data.ctrl[self.arm_act] = q
        finger = FINGER_MAX if gripper_open else 0.0
        self.data.qpos[self.finger_qpos_adr] = finger
        self.data.ctrl[self.gripper_act] = 1.0 if gripper_open else 0.0
        self._mujoco.mj_forward(self.model, self.data)

    # --- contacts ----------------------------------------------------------------------------
    def _contact_pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every active contact both ways round: ``(2 * ncon,)`` geoms ``a``, the geoms ``b`` they touch and the
        contact distances (m)."""
        ncon = int(self.data.ncon)
        contact = self.data.contact
        geom = np.asarray(contact.geom, np.int64).reshape(-1, 2)[:ncon]
        dist = np.asarray(contact.dist, np.float64).reshape(-1)[:ncon]
        return (np.concatenate([geom[:, 0], geom[:, 1]]), np.concatenate([geom[:, 1], geom[:, 0]]),
                np.concatenate([dist, dist]))

    def held_objects(self) -> set[int]:
        """Object ids touched by both fingers (i.e. grasped)."""
        a, b, _ = self._contact_pairs()
        touching = self.finger_geoms[a] & (self.geom_to_object[b] >= 0)
        pairs = np.unique(np.stack([self.geom_to_object[b][touching], a[touching]], axis=1), axis=0)
        objects, fingers = np.unique(pairs[:, 0], return_counts=True)
        return {int(obj) for obj in objects[fingers >= 2]}

    def _arm_contacts(self, allowed_objects: set[int]) -> list[str]:
        """Names of the scene geoms (not the robot's, not ``allowed_objects``) the robot presses into by more
        than 0.1 mm."""
        a, b, dist = self._contact_pairs()
        hits = (self.robot_geoms[a] & ~self.robot_geoms[b] & ~(dist > -1e-4)
                & ~np.isin(self.geom_to_object[b], list(allowed_objects)))
        return [self.geom_names[g] or f"geom{g}" for g in b[hits].tolist()]

    # --- motion ------------------------------------------------------------------------------
    def _plan(self, goal: np.ndarray, ignore_collision: bool, q_goal: np.ndarray, flipped: bool
              ) -> list[np.ndarray] | None:
        """Joint waypoints from the current state to the goal, or ``None`` if a waypoint fails IK."""
        goal = goal.copy()
        if flipped:
            goal[:3, :3] = goal[:3, :3] @ FLIP_Z
        start = self.tcp_pose()
        if ignore_collision:
            segments = [goal]
        else:
            safe = max(SAFE_HEIGHT, start[2, 3], goal[2, 3])
            up = start.copy()
            up[2, 3] = safe
            across = goal.copy()
            across[2, 3] = safe
            segments = []
            last = start
            for pose in (up, across, goal):
                if np.linalg.norm(pose[:3, 3] - last[:3, 3]) > 1e-3 or pose is goal:
                    segments.append(pose)
                    last = pose
        poses = []
        current = start
        for seg in segments:
            poses.extend(cartesian_waypoints(current, seg))
            current = seg
        q = self.arm_q
        path = []
        for pose in poses[:-1]:
            q_next = self.ik.solve(pose, q, max_iterations=60)
            if q_next is None:
                return None
            path.append(q_next)
            q = q_next
        path.append(q_goal)
        return path

    def _run_path(self, path: list[np.ndarray], check_collisions: bool) -> list[str]:
        """Track joint waypoints with the servos; returns arm contacts seen (if checked)."""
        m, d = self.model, self.data
        dt = m.opt.timestep
        allowed = self.held_objects()
        contacts: list[str] = []
        q_prev = d.ctrl[self.arm_act].copy()
        tcp_prev = self.ik.forward(q_prev)[:3, 3]
        for q in path:
            tcp = self.ik.forward(q)[:3, 3]
            duration = max(float(np.abs(q - q_prev).max()) / JOINT_SPEED,
                           float(np.linalg.norm(tcp - tcp_prev)) / CART_SPEED, 2 * dt)
            steps = max(1, int(round(duration / dt)))
            for k in range(1, steps + 1):
                d.ctrl[self.arm_act] = q_prev + (q - q_prev) * (k / steps)
                self._mujoco.mj_step(m, d)
                if check_collisions and k % 5 == 0:
                    contacts.extend(self._arm_contacts(allowed))
            q_prev, tcp_prev = q, tcp
        for _ in range(int(SETTLE_TIME / dt)):
            self._mujoco.mj_step(m, d)
        if check_collisions:
            contacts.extend(self._arm_contacts(allowed))
        return sorted(set(contacts))

    def actuate_gripper(self, open_: bool) -> None:
        """Open or close the gripper and let it settle."""
        target = 1.0 if open_ else 0.0
        if self.data.ctrl[self.gripper_act] == target and \
                (self.gripper_opening() > 0.95 if open_ else True):
            return
        self.data.ctrl[self.gripper_act] = target
        for _ in range(int(GRIPPER_TIME / self.model.opt.timestep)):
            self._mujoco.mj_step(self.model, self.data)

    def move_to(self, target: np.ndarray, ignore_collision: bool) -> MotionResult:
        """Move the TCP to ``target`` (4x4) without touching the gripper."""
        target = np.asarray(target, np.float64)
        q_goal, flipped = self.ik.solve_either(target, self.arm_q)
        if q_goal is None:
            p = np.round(target[:3, 3], 3).tolist()
            return MotionResult("unreachable", message=f"no IK solution for TCP target at {p} m "
                                "(also tried the grasp turned 180 degrees about the gripper axis)")
        path = self._plan(target, ignore_collision, q_goal, flipped)
        if path is None:
            if ignore_collision:
                return MotionResult("unreachable", message="the straight Cartesian path leaves the "
                                    "reachable space", flipped=flipped)
            path = [q_goal]  # joint-space fallback
        contacts = self._run_path(path, check_collisions=not ignore_collision)
        pos_err, rot_err = pose_error(self.tcp_pose(), target)
        if contacts:
            return MotionResult("collided", pos_err, rot_err, f"the arm touched {contacts}", contacts, flipped)
        if pos_err > REACH_TOLERANCE[0] or rot_err > REACH_TOLERANCE[1]:
            return MotionResult("blocked", pos_err, rot_err,
                                f"target not reached (error {pos_err * 1000:.1f} mm, {rot_err:.1f} deg)",
                                flipped=flipped)
        return MotionResult("reached", pos_err, rot_err, "reached", flipped=flipped)
