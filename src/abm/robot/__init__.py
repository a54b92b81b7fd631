"""Running a trained policy outside ``abm eval``: camera and arm interfaces and their kinds
(:mod:`abm.robot.kinds`), motion limits and the deployment loop (``abm run``), tested with a recorded camera, a
dry-run arm and the MuJoCo arm. Real hardware: :mod:`abm.robot.realsense` (RealSense cameras), :mod:`abm.robot.ur`
(UR arm, grippers) and :mod:`abm.robot.demonstrations` (demonstrations recorded on a robot, stored as episodes);
imported on demand, as their SDKs are optional (docs/real-robot.md)."""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.robot.devices import DryRunArm, ReplayCamera, SimRobot, record_observations
    from abm.robot.kinds import ARM_KINDS, CAMERA_KINDS, Arm, Camera, DeviceKind, register_arm, register_camera
    from abm.robot.limits import LimitError, MotionLimits
    from abm.robot.run import NoTargetError, RobotConfig, run_robot

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = ["ARM_KINDS", "CAMERA_KINDS", "Arm", "Camera", "DeviceKind", "DryRunArm", "LimitError", "MotionLimits",
           "NoTargetError", "ReplayCamera", "RobotConfig", "SimRobot", "record_observations", "register_arm",
           "register_camera", "run_robot"]
