"""Running a trained policy outside ``abm eval``: camera and arm interfaces, motion limits and the
deployment loop (``abm run``), tested with a recorded camera, a dry-run arm and the MuJoCo arm. Real
hardware: :mod:`abm.robot.realsense` (RealSense cameras), :mod:`abm.robot.ur` (UR arm, grippers) and
:mod:`abm.robot.demonstrations` (demonstrations recorded on a robot, stored as episodes); imported on
demand, as their SDKs are optional (docs/real-robot.md)."""

from abm.lazy import lazy_exports

# imported on first use (abm.lazy), so importing the package (every `abm` command does) stays light
__getattr__, __dir__ = lazy_exports(__name__, {
    "abm.robot.devices": ("DryRunArm", "ReplayCamera", "SimRobot", "record_observations",),
    "abm.robot.limits": ("LimitError", "MotionLimits",),
    "abm.robot.run": ("NoTargetError", "RobotConfig", "run_robot",),
})

__all__ = ["DryRunArm", "LimitError", "MotionLimits", "NoTargetError", "ReplayCamera", "RobotConfig", "SimRobot",
           "record_observations", "run_robot"]
