"""What a robot file may name: the :class:`Camera` and :class:`Arm` interfaces and the registries of their
implementations, :data:`CAMERA_KINDS` and :data:`ARM_KINDS` (``cameras: {kind: ..., options}``, ``arm: {kind: ...}``).

* cameras: ``replay`` (:class:`abm.robot.devices.ReplayCamera`: frames recorded with ``abm record``), ``sim``
  (:class:`abm.robot.devices.SimRobot`: the MuJoCo scene, shared with an arm of kind ``sim``), ``realsense``
  (:class:`abm.robot.realsense.RealSenseCamera`: Intel RealSense RGB-D cameras, pyrealsense2);
* arms: ``dry-run`` (:class:`abm.robot.devices.DryRunArm`: moves nothing, logs the commands), ``sim`` (the simulated
  Panda of that scene), ``ur`` (:class:`abm.robot.ur.URArm`: a Universal Robots arm over RTDE, ur_rtde).

An entry (:class:`DeviceKind`) declares the options its section takes (checked when the file loads, before anything
is built) and names its builder as ``"module:callable"``, imported only when the robot is built (the SDKs are
optional). **Adding a camera or an arm**: its class in a module of its own, with a builder taking the section's
options (an arm's also ``limits=`` and ``read_only=``), and its :func:`register_camera` / :func:`register_arm` entry
here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from abm.configuration import SPLITS
from abm.registry import Registry
from abm.schema import Field, any_mapping, integer, number, strings, text, vector

if TYPE_CHECKING:
    import numpy as np

    from abm.types import CameraFrame, KeyframeAction


@runtime_checkable
class Camera(Protocol):
    """A source of RGB-D frames: :meth:`read` returns one frame per camera (RGB, metric depth, intrinsics,
    camera-to-base extrinsics). Optional: ``object_names`` (segmentation id -> name; a recording's or the
    simulator's, empty for real cameras), ``instruction`` (a recording's), ``close()``."""

    def read(self) -> dict[str, CameraFrame]: ...


@runtime_checkable
class Arm(Protocol):
    """An arm with a gripper: :meth:`state` is ``(gripper pose (4, 4) in the base frame, metres; opening in
    [0, 1])``, :meth:`move` goes to a keyframe and returns a status word (``reached``, ``dry-run``, ...).
    Optional: ``stop()`` (called on Ctrl-C during a motion), ``success()`` (a simulated task's), ``close()``."""

    def state(self) -> tuple[np.ndarray, float]: ...

    def move(self, action: KeyframeAction) -> str: ...


@dataclass(frozen=True)
class DeviceKind:
    """One kind of camera source or arm: an entry of :data:`CAMERA_KINDS` or :data:`ARM_KINDS`.

    Attributes:
        options: the options its section takes besides ``kind`` (checked when the robot file loads).
        build: ``"module:callable"`` building it from those options (a camera: ``callable(options)``; an arm:
            ``callable(options, limits=MotionLimits, read_only=bool)``, where ``read_only`` means the arm is only
            asked for its state: a dry run's start pose). Empty for the kinds :class:`abm.robot.run.RobotConfig`
            builds itself (``sim``'s shared scene, the ``dry-run`` arm).
        description: one line on what it is.
        simulated: it is the simulated scene, one object that a camera and an arm of this kind share.
    """

    options: Mapping[str, Field]
    build: str
    description: str
    simulated: bool = False


#: camera sources of a robot file, by ``kind``
CAMERA_KINDS: Registry[DeviceKind] = Registry("camera kind")
#: arms of a robot file, by ``kind``
ARM_KINDS: Registry[DeviceKind] = Registry("arm kind")


def register_camera(name: str, kind: DeviceKind) -> DeviceKind:
    """Add a camera kind to :data:`CAMERA_KINDS`."""
    return CAMERA_KINDS.register(name, kind)


def register_arm(name: str, kind: DeviceKind) -> DeviceKind:
    """Add an arm kind to :data:`ARM_KINDS`."""
    return ARM_KINDS.register(name, kind)


SIM_OPTIONS: dict[str, Field] = {"task": Field(text()), "split": Field(text(SPLITS)),
                                 "seed": Field(integer(0, 2**63 - 1)), "resolution": Field(integer(8, 4096))}
_POSITIVE = Field(number(0.0, low_open=True))

register_camera("replay", DeviceKind({"path": Field(text(), required=True)},
                                     "abm.robot.devices:ReplayCamera.from_config",
                                     "frames recorded with abm record (abm.robot.record_observations)"))
register_camera("sim", DeviceKind(SIM_OPTIONS, "", "the cameras of the MuJoCo scene an arm of kind sim moves in",
                                  simulated=True))
register_camera("realsense", DeviceKind(
    {"serials": Field(strings, required=True), "calibration": Field(text()), "width": Field(integer(1)),
     "height": Field(integer(1)), "fps": Field(integer(1)), "timeout_ms": Field(integer(1)),
     "warmup_frames": Field(integer(0))},
    "abm.robot.realsense:RealSenseCamera.from_config", "Intel RealSense RGB-D cameras (pyrealsense2)"))

register_arm("dry-run", DeviceKind({}, "", "moves nothing: logs each commanded keyframe"))
register_arm("sim", DeviceKind({**SIM_OPTIONS, "task": Field(text(), required=True)}, "",
                               "the simulated Panda of one ABM-Bench scene", simulated=True))
register_arm("ur", DeviceKind(
    {"host": Field(text(), required=True), "speed": _POSITIVE, "acceleration": _POSITIVE,
     "tcp_offset": Field(vector(6)), "base_pose": Field(vector(6)), "tolerance_m": _POSITIVE,
     "tolerance_deg": _POSITIVE, "motion_timeout_s": _POSITIVE, "gripper": Field(any_mapping)},
    "abm.robot.ur:URArm.from_config", "a Universal Robots arm over RTDE (ur_rtde), with a gripper"))
