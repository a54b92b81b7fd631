"""Universal Robots arms (ur_rtde) behind the arm interface of :mod:`abm.robot.devices`, with a pluggable
gripper.

* :class:`URArm` moves the tool centre point in a straight line (``moveL``) to each keyframe, then opens
  or closes the gripper (as the simulator does). A keyframe pose (4 x 4 in abm's base frame, metres) becomes
  the UR pose ``[x, y, z, rx, ry, rz]`` (metres, rotation vector in radians) in the controller's base frame.
* Grippers implement :class:`Gripper` (``set_open(bool)``, ``opening() -> [0, 1]``):
  :class:`DryRunGripper` (logs only), :class:`URDigitalOutputGripper` (a tool or standard digital output
  through ``rtde_io``, e.g. a pneumatic or a Robotiq gripper in I/O mode), or any class named in the
  robot YAML as ``module:Class``.

``rtde_control`` / ``rtde_receive`` / ``rtde_io`` (``pip install ur_rtde``) are imported only when an arm is
opened; tests pass fake modules.
"""

from __future__ import annotations

import importlib
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from scipy.spatial.transform import Rotation

from abm.errors import ConfigError, ExternalError
from abm.robot.limits import MotionLimits
from abm.types import KeyframeAction

log = logging.getLogger(__name__)

MAX_SPEED = 0.5  # m/s: the largest tool speed URArm accepts for a learned policy
MAX_ACCELERATION = 1.5  # m/s^2


def import_ur_rtde(name: str) -> Any:
    """One of the ur_rtde modules (``rtde_control``, ``rtde_receive``, ``rtde_io``), or an ExternalError
    that says how to install it."""
    try:
        return importlib.import_module(name)
    except ImportError as err:
        raise ExternalError(f"UR arms need ur_rtde ({name} is missing): pip install ur_rtde "
                            "(see docs/real-robot.md)") from err


def pose_to_ur(matrix: np.ndarray) -> list[float]:
    """``(4, 4)`` pose -> UR pose ``[x, y, z, rx, ry, rz]`` (metres; rotation vector, radians)."""
    m = np.asarray(matrix, np.float64)
    return [*m[:3, 3].tolist(), *Rotation.from_matrix(m[:3, :3]).as_rotvec().tolist()]


def ur_to_pose(pose: Sequence[float]) -> np.ndarray:
    """UR pose ``[x, y, z, rx, ry, rz]`` -> ``(4, 4)`` transform."""
    p = np.asarray(pose, np.float64).reshape(-1)
    if p.shape != (6,):
        raise ValueError(f"a UR pose is [x, y, z, rx, ry, rz], got {list(pose)}")
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(p[3:]).as_matrix()
    out[:3, 3] = p[:3]
    return out


@runtime_checkable
class Gripper(Protocol):
    """A gripper the arm opens and closes after each motion."""

    def set_open(self, open_: bool) -> None:
        """Open (True) or close (False); returns when done."""

    def opening(self) -> float:
        """Current opening in ``[0, 1]`` (1 = fully open)."""


class DryRunGripper:
    """Moves nothing: logs each command and remembers the state."""

    def __init__(self, open_: bool = True) -> None:
        self.is_open = bool(open_)
        self.commands: list[bool] = []

    def set_open(self, open_: bool) -> None:
        self.commands.append(bool(open_))
        self.is_open = bool(open_)
        log.info("gripper (dry run): %s", "open" if open_ else "close")

    def opening(self) -> float:
        return 1.0 if self.is_open else 0.0


class URDigitalOutputGripper:
    """A gripper switched by one of the controller's standard digital outputs (``rtde_io``).

    Args:
        io: an ``rtde_io.RTDEIOInterface``.
        receive: an ``rtde_receive.RTDEReceiveInterface`` (reads the output back for :meth:`opening`).
        output: the standard digital output, 0-7.
        closed_level: the output level that closes the gripper.
        settle_s: seconds to wait after switching (fingers move, pressure builds up).
    """

    def __init__(self, io: Any, receive: Any, output: int = 0, closed_level: bool = True, settle_s: float = 0.5,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not 0 <= int(output) <= 7:
            raise ConfigError(f"gripper output {output} is not a standard digital output (0-7)")
        self.io, self.receive, self.output = io, receive, int(output)
        self.closed_level, self.settle_s, self.sleep = bool(closed_level), float(settle_s), sleep

    def set_open(self, open_: bool) -> None:
        level = self.closed_level != bool(open_)
        if not self.io.setStandardDigitalOut(self.output, level):
            raise ExternalError(f"the UR controller refused to set digital output {self.output}")
        self.sleep(self.settle_s)

    def opening(self) -> float:
        return 0.0 if bool(self.receive.getDigitalOutState(self.output)) == self.closed_level else 1.0


class URArm:
    """A UR arm controlled over RTDE.

    Args:
        host: the controller's IP address or host name.
        gripper: a :class:`Gripper` (default :class:`DryRunGripper`, with a warning).
        speed: tool speed of ``moveL`` in m/s (at most ``MAX_SPEED``).
        acceleration: tool acceleration in m/s^2 (at most ``MAX_ACCELERATION``).
        tcp_offset: ``[x, y, z, rx, ry, rz]`` of abm's tool centre point in the controller's active TCP frame
            (metres, rotation vector; default identity). Applied here, not on the controller, so read-only
            connections (dry runs, recording) see the same TCP; keep the pendant's TCP the same throughout (e.g.
            the flange, all zeros). abm's TCP has +z along the approach direction and +y along the finger axis.
        base_pose: ``[x, y, z, rx, ry, rz]`` of the controller's base frame in abm's base frame (default
            identity); use it when the table is not along the controller's +x.
        limits: checked again here before each motion (``run_robot`` checks them first).
        read_only: connect only ``rtde_receive`` (reading poses; no motion), e.g. for dry runs and recording.
        tolerance_m / tolerance_deg: how close the reached TCP pose must be for status ``reached``.
        motion_timeout_s: a motion still running after this long is stopped (status ``timeout``).
        rtde_control / rtde_receive: the ur_rtde modules (default: imported here).
    """

    START_TIMEOUT_S = 1.0  # s to wait for an asynchronous moveL to show up as running

    def __init__(self, host: str, gripper: Gripper | None = None, speed: float = 0.1, acceleration: float = 0.3,
                 tcp_offset: Sequence[float] | None = None, base_pose: Sequence[float] | None = None,
                 limits: MotionLimits | None = None, read_only: bool = False, tolerance_m: float = 0.005,
                 tolerance_deg: float = 2.0, motion_timeout_s: float = 30.0, poll_s: float = 0.02,
                 rtde_control: Any = None, rtde_receive: Any = None) -> None:
        if not 0 < speed <= MAX_SPEED or not 0 < acceleration <= MAX_ACCELERATION:
            raise ConfigError(f"UR speed {speed} m/s / acceleration {acceleration} m/s^2 out of range: "
                              f"0 < speed <= {MAX_SPEED}, 0 < acceleration <= {MAX_ACCELERATION}")
        self.host, self.speed, self.acceleration = str(host), float(speed), float(acceleration)
        self.limits, self.read_only = limits, bool(read_only)
        self.tolerance_m, self.tolerance_deg = float(tolerance_m), float(tolerance_deg)
        self.motion_timeout_s, self.poll_s = float(motion_timeout_s), float(poll_s)
        self.base = np.eye(4) if base_pose is None else ur_to_pose(base_pose)
        self.tcp = np.eye(4) if tcp_offset is None else ur_to_pose(tcp_offset)
        if gripper is None:
            log.warning("UR arm without a gripper: gripper commands are only logged")
            gripper = DryRunGripper()
        self.gripper = gripper
        receive_mod = rtde_receive if rtde_receive is not None else import_ur_rtde("rtde_receive")
        self.receive = receive_mod.RTDEReceiveInterface(self.host)
        self.control = None
        if not self.read_only:
            control_mod = rtde_control if rtde_control is not None else import_ur_rtde("rtde_control")
            self.control = control_mod.RTDEControlInterface(self.host)

    def target_pose(self, action: KeyframeAction) -> list[float]:
        """The UR pose ``[x, y, z, rx, ry, rz]`` (controller base frame) that ``moveL`` gets for ``action``."""
        return pose_to_ur(np.linalg.inv(self.base) @ action.matrix @ np.linalg.inv(self.tcp))

    def state(self) -> tuple[np.ndarray, float]:
        """``(TCP pose (4, 4) in abm's base frame, gripper opening in [0, 1])``."""
        pose = self.base @ ur_to_pose(self.receive.getActualTCPPose()) @ self.tcp
        return pose, float(self.gripper.opening())

    def move(self, action: KeyframeAction) -> str:
        """Limits, ``moveL`` (asynchronous, polled so Ctrl-C reaches Python), then the gripper.

        Returns:
            ``reached``, ``rejected`` (the controller refused the target), ``timeout`` or ``missed`` (the
            motion ended away from the target); the gripper is actuated only after ``reached``.
        """
        if self.control is None:
            raise RuntimeError("this URArm is read-only (no rtde_control connection); it cannot move")
        if self.limits is not None:
            self.limits.check(self.state()[0], action)
        target = self.target_pose(action)
        log.info("UR moveL to %s at %.2f m/s", np.round(target, 4).tolist(), self.speed)
        if not self.control.moveL(target, self.speed, self.acceleration, True):
            return "rejected"
        start = time.monotonic()
        # the controller reports the asynchronous motion as running (progress >= 0) a moment after moveL returns
        while self.control.getAsyncOperationProgress() < 0 and time.monotonic() - start < self.START_TIMEOUT_S:
            time.sleep(self.poll_s)
        while self.control.getAsyncOperationProgress() >= 0:
            if time.monotonic() - start > self.motion_timeout_s:
                self.stop()
                return "timeout"
            time.sleep(self.poll_s)
        reached = ur_to_pose(self.receive.getActualTCPPose())
        error_m = float(np.linalg.norm(reached[:3, 3] - np.asarray(target[:3])))
        error_deg = float(np.degrees((Rotation.from_matrix(reached[:3, :3]).inv()
                                      * Rotation.from_rotvec(target[3:])).magnitude()))
        if error_m > self.tolerance_m or error_deg > self.tolerance_deg:
            log.warning("UR motion ended %.1f mm / %.1f deg from the target", 1000 * error_m, error_deg)
            return "missed"
        self.gripper.set_open(action.gripper_open)
        return "reached"

    def stop(self, deceleration: float = 4.0) -> None:
        """Decelerate to a stop (m/s^2); used on Ctrl-C and on a motion timeout."""
        if self.control is not None:
            self.control.stopL(deceleration)

    def close(self) -> None:
        """Stop the control script and disconnect."""
        if self.control is not None:
            self.control.stopScript()
            self.control.disconnect()
        self.receive.disconnect()

    @classmethod
    def from_config(cls, options: Mapping[str, Any], limits: MotionLimits | None = None, read_only: bool = False,
                    gripper_dry_run: bool | None = None, modules: Mapping[str, Any] | None = None) -> URArm:
        """From the robot YAML's ``arm`` section: ``{kind: ur, host, speed, acceleration, tcp_offset, base_pose,
        tolerance_m, tolerance_deg, motion_timeout_s, gripper: {kind: dry-run | digital-output | module:Class,
        ...}}``. ``gripper_dry_run`` (default ``read_only``) logs gripper commands instead of sending them;
        ``modules`` maps ``rtde_control`` / ``rtde_receive`` / ``rtde_io`` to (fake) modules."""
        opts = {k: v for k, v in options.items() if k != "kind"}
        allowed = {"host", "speed", "acceleration", "tcp_offset", "base_pose", "tolerance_m", "tolerance_deg",
                   "motion_timeout_s", "gripper"}
        unknown = set(opts) - allowed
        if unknown:
            raise ConfigError(f"arm: unknown ur options {sorted(unknown)} (allowed: {sorted(allowed)})")
        if "host" not in opts:
            raise ConfigError("arm: kind ur needs host (the controller's IP address)")
        modules = dict(modules or {})
        gripper_opts = dict(opts.pop("gripper", None) or {"kind": "dry-run"})
        arm = cls(limits=limits, read_only=read_only, rtde_control=modules.get("rtde_control"),
                  rtde_receive=modules.get("rtde_receive"), gripper=DryRunGripper(), **opts)
        dry = read_only if gripper_dry_run is None else gripper_dry_run
        arm.gripper = make_gripper(gripper_opts, arm, modules.get("rtde_io"), dry_run=dry)
        return arm


def make_gripper(options: Mapping[str, Any], arm: URArm, rtde_io: Any = None, dry_run: bool = False) -> Gripper:
    """A gripper from the ``arm.gripper`` YAML section (``dry_run``: a :class:`DryRunGripper` that starts in the
    real gripper's state where that can be read)."""
    opts = dict(options)
    kind = str(opts.pop("kind", "dry-run"))
    if kind == "dry-run":
        return DryRunGripper()
    if kind == "digital-output":
        if dry_run:
            level = bool(arm.receive.getDigitalOutState(int(opts.get("output", 0))))
            return DryRunGripper(open_=level != bool(opts.get("closed_level", True)))
        io_mod = rtde_io if rtde_io is not None else import_ur_rtde("rtde_io")
        return URDigitalOutputGripper(io_mod.RTDEIOInterface(arm.host), arm.receive, **opts)
    if ":" in kind:
        if dry_run:
            return DryRunGripper()
        module, _, name = kind.partition(":")
        gripper = getattr(importlib.import_module(module), name)(**opts)
        if not isinstance(gripper, Gripper):
            raise ConfigError(f"gripper {kind} lacks set_open(bool) / opening() (abm.robot.ur.Gripper)")
        return gripper
    raise ConfigError(f"unknown gripper kind {kind!r}; use dry-run, digital-output or module:Class")
