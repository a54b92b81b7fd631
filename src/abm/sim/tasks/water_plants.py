"""water_plants: "water the plant with the X" (X a mug or pot).

The expert grasps the container across its body, carries it above the (procedural, fixed) potted plant
and tilts it. Success = the container is held, tilted more than ``MIN_TILT_DEG`` from upright, and the
centre of its opening is above the plant's leaves within ``POUR_RADIUS`` of the plant's axis.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.props import PLANT_HEIGHT, POT_RADIUS
from abm.sim.tasks.base import (
    APPROACH_HEIGHT,
    LIFT_HEIGHT,
    Task,
    TaskInstance,
    action,
    grasp_pose,
    register_task,
    top_down_pose,
)
from abm.types import KeyframeAction

NUM_DISTRACTORS = 1          # other containers of the split (plus one grocery)
MIN_TILT_DEG = 45.0
POUR_TILTS_DEG = (70.0, 60.0, 55.0)  # tilts the expert tries, degrees
POUR_RADIUS = POT_RADIUS     # m, horizontal tolerance of the opening around the plant axis
POUR_CLEARANCE = 0.06        # m, opening above the leaves when pouring


def opening_point(sim, index: int) -> np.ndarray:
    """``(3,)`` centre of the container's opening (top of its collision box), world."""
    geo = object_geometry(sim.scene.objects[index].name)
    pose = sim.object_pose(index)
    top = np.array([geo.center[0], geo.center[1], geo.upper[2]])
    return pose[:3, :3] @ top + pose[:3, 3]


def _tilted(pose: np.ndarray, angle: float) -> np.ndarray:
    """``pose`` rotated by ``angle`` about its own x axis (perpendicular to the finger axis)."""
    c, s = np.cos(angle), np.sin(angle)
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return out


def pour_candidates(plant_xy: np.ndarray) -> list[tuple[float, float, float]]:
    """``(finger_yaw, tilt sign, tilt_deg)`` tried in order: rolling the wrist sideways (fingers
    tangential to the robot -> plant direction) first, then pitching, with decreasing tilts."""
    radial = float(np.arctan2(plant_xy[1], plant_xy[0]))
    return [(yaw, sign, tilt) for tilt in POUR_TILTS_DEG
            for yaw in (radial + np.pi / 2, radial) for sign in (1.0, -1.0)]


@register_task
class WaterPlants(Task):
    name = "water_plants"
    templates = ("water the plant with the {target}", "use the {target} to water the plant")
    categories = ("mug",)
    seed_salt = 5
    fixtures = (("plant", "plant"),)
    distractors = NUM_DISTRACTORS
    borrowed_distractors = (("place_food", 1),)  # and one grocery of the same split

    def success(self, sim, instance: TaskInstance) -> bool:
        target, plant = instance.info["target"], instance.info["plant"]
        if target not in sim.held_objects():
            return False
        pose = sim.object_pose(target)
        tilt = np.degrees(np.arccos(np.clip(pose[2, 2], -1.0, 1.0)))
        opening = opening_point(sim, target)
        axis = sim.object_pose(plant)[:2, 3]
        above = np.hypot(*(opening[:2] - axis)) < POUR_RADIUS and opening[2] > PLANT_HEIGHT
        return bool(tilt > MIN_TILT_DEG and above)

    def expert(self, sim, instance: TaskInstance) -> Iterator[KeyframeAction]:
        target = instance.info["target"]
        grasp = grasp_pose(sim, target)
        above = grasp.copy()
        above[2, 3] += APPROACH_HEIGHT
        yield action(above, True, False, "approach")
        yield action(grasp, False, True, "grasp")
        lift = grasp.copy()
        lift[2, 3] += LIFT_HEIGHT
        yield action(lift, False, True, "lift")
        # Opening in the TCP frame, measured now that the container is held.
        tcp = sim.robot.tcp_pose()
        local = tcp[:3, :3].T @ (opening_point(sim, target) - tcp[:3, 3])
        plant_xy = sim.object_pose(instance.info["plant"])[:2, 3]
        pour = None
        for finger_yaw, sign, tilt in pour_candidates(plant_xy):
            pose = _tilted(top_down_pose(np.zeros(3), finger_yaw), sign * np.radians(tilt))
            offset = pose[:3, :3] @ local
            pose[:3, 3] = [plant_xy[0] - offset[0], plant_xy[1] - offset[1],
                           PLANT_HEIGHT + POUR_CLEARANCE - offset[2]]
            if sim.robot.ik.solve_either(pose, sim.robot.arm_q)[0] is not None:
                pour = pose
                break
        if pour is None:  # nothing solves: try the first candidate anyway (it will report unreachable)
            finger_yaw, sign, tilt = pour_candidates(plant_xy)[0]
            pour = _tilted(top_down_pose(np.asarray([*plant_xy, PLANT_HEIGHT + 0.1]), finger_yaw),
                           sign * np.radians(tilt))
        carry = top_down_pose(pour[:3, 3].copy(), finger_yaw)
        carry[2, 3] = max(pour[2, 3] + 0.05, lift[2, 3])
        yield action(carry, False, False, "move")  # move above the plant
        yield action(pour, False, True, "pour")
