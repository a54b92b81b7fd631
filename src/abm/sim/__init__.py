"""ABM-Bench: the MuJoCo simulation benchmark (scene, cameras, robot control, objects, tasks).

Heavy imports (mujoco, mink) happen in the submodules; import what you need from them, e.g.::

    from abm.sim.env import make_env
    env = make_env("place_food", split="seen", seed=0, resolution=128)
    obs = env.reset()
    obs, success, info = env.step(action)
"""

from __future__ import annotations

import os
import platform

# Headless rendering by default on Linux without a display; a user setting wins.
if platform.system() == "Linux" and not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
