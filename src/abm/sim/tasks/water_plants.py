"""water_plants: "water the plant with the X" (X a mug or pot).

The expert grasps the container across its body, carries it above the (procedural, fixed) potted plant
and tilts it. Success = the container is held, tilted more than ``MIN_TILT_DEG`` from upright, and the
centre of its opening is above the plant's leaves within ``POUR_RADIUS`` of the plant's axis.

The grasp is labelled by what the policy's views can see. A mug's handle sticks out about 1.5 cm from a round
body (one pixel of the 64² views over the 1 m workspace), so a grasp yaw that follows the handle cannot be
read from them. Instead every container stands with its handle axis (the long side of its collision box)
within ``HANDLE_SPREAD_DEG`` of the direction across the reference finger yaw (``GRIPPER_REFERENCE_YAW_DEG``,
handle towards either side), and the expert always grasps at that reference yaw: the approach, grasp and
lift labels are the same in every scene, and the fingers stay at least 60 degrees from the handle. Version 2
of the task (:data:`abm.types.TASK_DATA_VERSIONS`); version 1 drew any container yaw and grasped across the
box's narrower side, a yaw the views could not resolve.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.geometry.rotations import GRIPPER_REFERENCE_YAW_DEG
from abm.sim.catalog import catalog_entry, object_geometry
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

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 1          # other containers of the split (plus one grocery)
MIN_TILT_DEG = 45.0
POUR_TILTS_DEG = (70.0, 60.0, 55.0)  # tilts the expert tries, degrees
POUR_RADIUS = POT_RADIUS     # m, horizontal tolerance of the opening around the plant axis
POUR_CLEARANCE = 0.06        # m, opening above the leaves when pouring
GRASP_YAW = float(np.radians(GRIPPER_REFERENCE_YAW_DEG))  # rad, finger yaw of every container grasp
HANDLE_SPREAD_DEG = 30.0     # degrees, a container's handle axis around the direction across GRASP_YAW


def narrow_axis_yaw(name: str) -> float:
    """Yaw (rad) of the narrower horizontal side of a container's collision box in its own frame: 0 (local
    x) or pi/2 (local y). The handle (and a moka pot's spout) lie along the other, longer side."""
    geo = object_geometry(name)
    return 0.0 if geo.upper[0] - geo.lower[0] < geo.upper[1] - geo.lower[1] else float(np.pi / 2)


def handle_clear_yaw(name: str, drawn_yaw: float) -> float:
    """The container yaw (rad) that a layout's uniformly drawn yaw in [-pi, pi) maps to: its narrower side
    within ``HANDLE_SPREAD_DEG`` of ``GRASP_YAW`` (so the handle axis lies across it), the handle to one side
    for a drawn yaw < 0 and to the other for >= 0. Uniform over that set; other objects' poses are unchanged."""
    fraction = float(np.mod(drawn_yaw + np.pi, np.pi) / np.pi)
    turn = np.radians(HANDLE_SPREAD_DEG) * (2.0 * fraction - 1.0) + (np.pi if drawn_yaw >= 0 else 0.0)
    yaw = GRASP_YAW + turn - narrow_axis_yaw(name)
    return float(np.mod(yaw + np.pi, 2 * np.pi) - np.pi)


def opening_point(sim: Simulation, index: int) -> np.ndarray:
    """``(3,)`` centre of the container's opening (top of its collision box), world."""
    geo = object_geometry(sim.scene.objects[index].name)
    pose = sim.object_pose(index)
    top = np.array([geo.center[0], geo.center[1], geo.upper[2]])
    point: np.ndarray = pose[:3, :3] @ top + pose[:3, 3]
    return point


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
    destination = "plant"
    seed_salt = 5
    fixtures = (("plant", "plant"),)
    distractors = NUM_DISTRACTORS
    borrowed_distractors = (("place_food", 1),)  # and one grocery of the same split

    def sample(self, seed: int, split: str) -> TaskInstance:
        """The base layout, every container of the task's category turned by :func:`handle_clear_yaw`."""
        instance = super().sample(seed, split)
        objects = [dataclasses.replace(o, yaw=handle_clear_yaw(o.name, o.yaw))
                   if catalog_entry(o.name).category in self.categories else o
                   for o in instance.scene.objects]
        instance.scene = dataclasses.replace(instance.scene, objects=objects)
        return instance

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        target, plant = instance.info["target"], instance.info["plant"]
        if target not in sim.held_objects():
            return False
        pose = sim.object_pose(target)
        tilt = np.degrees(np.arccos(np.clip(pose[2, 2], -1.0, 1.0)))
        opening = opening_point(sim, target)
        axis = sim.object_pose(plant)[:2, 3]
        above = np.hypot(*(opening[:2] - axis)) < POUR_RADIUS and opening[2] > PLANT_HEIGHT
        return bool(tilt > MIN_TILT_DEG and above)

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        target = instance.info["target"]
        # At the box's grasp point, fingers at the reference yaw (the handle lies across them, see sample).
        grasp = top_down_pose(grasp_pose(sim, target)[:3, 3], GRASP_YAW)
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
