"""Dense recording of a simulated episode at a fixed control rate (``abm data generate --dense``).

The keyframe controller steps physics itself (``mj_step`` inside :class:`abm.sim.arm_control.RobotController`).
:class:`DenseRecorder` sits between the controller and MuJoCo: every ``1 / fps`` seconds of simulated
time it renders the cameras and reads the joint state and the commanded servo targets. Before each
keyframe observation, :meth:`DenseRecorder.keyframe` holds the arm still (current controls) until the
next control tick, so every keyframe observation is one of the dense frames (at most one control period
of extra settling per keyframe; episodes recorded with ``--dense`` therefore differ slightly from
keyframe-only ones of the same seed).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from abm.errors import ConfigError
from abm.geometry.rotations import matrix_to_quat
from abm.sim.scene import PHYSICS_TIMESTEP
from abm.types import Observation, Trajectory

if TYPE_CHECKING:
    import mujoco

DEFAULT_FPS = 10.0


def control_period(fps: float, timestep: float = PHYSICS_TIMESTEP) -> int:
    """Physics steps per frame at ``fps``; ``ValueError`` unless ``1 / fps`` is a whole number of them."""
    period = 1.0 / float(fps) / timestep if fps > 0 else 0.0
    if round(period) < 1 or abs(period - round(period)) > 1e-6:
        raise ConfigError(f"--dense-fps {fps:g}: 1/fps must be a whole number of physics steps of "
                          f"{timestep * 1000:g} ms (e.g. 5, 10, 25 or 50)")
    return int(round(period))


class _SteppingClock:
    """The ``mujoco`` module with ``mj_step`` counted (and a frame captured every ``period`` steps)."""

    def __init__(self, module: Any, recorder: DenseRecorder) -> None:
        self._module = module
        self._recorder = recorder

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)

    def mj_step(self, model: mujoco.MjModel, data: mujoco.MjData, *args: Any) -> None:
        self._module.mj_step(model, data, *args)
        self._recorder._tick()


class DenseRecorder:
    """Records ``sim`` at ``fps`` frames per second of simulated time while it is attached.

    Args:
        sim: a :class:`abm.sim.simulation.Simulation` (already reset).
        fps: control rate; ``1 / fps`` must be a whole number of physics steps.
    """

    def __init__(self, sim: Any, fps: float = DEFAULT_FPS) -> None:
        self.sim, self.fps = sim, float(fps)
        self.period = control_period(fps, float(sim.model.opt.timestep))
        self.ticks = 0
        self.observations: list[Observation] = []
        self.joints: list[np.ndarray] = []
        self.commands: list[np.ndarray] = []
        self.tcp: list[np.ndarray] = []
        self.keyframe_frames: list[int] = []
        self._saved = (sim._mujoco, sim.robot._mujoco)
        clock = _SteppingClock(sim._mujoco, self)
        sim._mujoco = clock
        sim.robot._mujoco = clock
        self._capture()

    def _tick(self) -> None:
        self.ticks += 1
        if self.ticks % self.period == 0:
            self._capture()

    def _capture(self) -> None:
        sim, robot = self.sim, self.sim.robot
        d = sim.data
        self.observations.append(sim.observe())
        self.joints.append(np.concatenate([d.qpos[robot.arm_qpos_adr], d.qpos[robot.finger_qpos_adr]]))
        gripper = 1.0 if d.ctrl[robot.gripper_act] > 0.5 else 0.0
        self.commands.append(np.concatenate([d.ctrl[robot.arm_act], [gripper]]))
        pose = robot.tcp_pose()
        self.tcp.append(np.concatenate([pose[:3, 3], matrix_to_quat(pose[:3, :3])]))

    def keyframe(self) -> Observation:
        """Hold the arm still until the next control tick and return that frame as the keyframe observation."""
        mujoco = self.sim._mujoco
        while self.ticks % self.period:
            mujoco.mj_step(self.sim.model, self.sim.data)
        self.keyframe_frames.append(len(self.observations) - 1)
        return self.observations[-1]

    def detach(self) -> Trajectory:
        """Stop recording (MuJoCo is stepped directly again) and return the trajectory."""
        self.sim._mujoco, self.sim.robot._mujoco = self._saved
        n = len(self.observations)
        commands = np.array(self.commands)
        tcp = np.array(self.tcp)
        for t in range(1, n):  # sign-continuous quaternions (q and -q are the same turn)
            if np.dot(tcp[t, 3:], tcp[t - 1, 3:]) < 0:
                tcp[t, 3:] *= -1
        nxt = np.minimum(np.arange(n) + 1, n - 1)  # the command in effect until the next tick
        joint_actions = commands[nxt]
        ee_actions = np.concatenate([tcp[nxt], commands[nxt, 7:]], axis=1)
        return Trajectory(fps=self.fps, observations=self.observations, joint_positions=np.array(self.joints),
                          joint_actions=joint_actions, ee_actions=ee_actions,
                          keyframe_frames=np.array(self.keyframe_frames, np.int64))
