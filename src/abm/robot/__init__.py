"""Running a trained policy outside ``abm eval``: camera and arm interfaces, motion limits and the
deployment loop (``abm run``). Real-hardware adapters (RealSense, UR) are issue 15's remaining work;
the loop is tested with a recorded camera, a dry-run arm and the MuJoCo arm."""

from abm.robot.devices import DryRunArm, ReplayCamera, SimRobot, record_observations
from abm.robot.limits import LimitError, MotionLimits
from abm.robot.run import RobotConfig, run_robot

__all__ = ["DryRunArm", "LimitError", "MotionLimits", "ReplayCamera", "RobotConfig", "SimRobot",
           "record_observations", "run_robot"]
