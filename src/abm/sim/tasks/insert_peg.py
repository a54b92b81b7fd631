"""insert_peg: "put the ring on the X peg" (X a colour; the instruction's target is "X peg").

Procedural coloured square pegs are fixed to the table; a square ring lies on the table. The expert
grasps one side bar of the ring, carries the ring above the named peg, and drops it so that it slides
down around the peg. Success = the ring is released, encircles the named peg (peg axis inside the hole)
and has slid down below the peg's top.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.props import PEG_HALF, RING_BAR_HALF_WIDTH, RING_HALF_HEIGHT, RING_OUTER_HALF
from abm.sim.tasks.base import (
    DESTINATION_X,
    FINGER_REACH,
    Task,
    TaskInstance,
    pick_and_place,
    register_task,
    top_down_pose,
)
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2          # other pegs of the split
RING = "ring"
DROP_ABOVE_PEG = 0.006       # m, ring bottom above the peg top when released


def ring_grasp(sim: Simulation, ring: int) -> np.ndarray:
    """Top-down grasp across one of the ring's four bars: the one whose fingers stay clearest of others."""
    pose = sim.object_pose(ring)
    bar = RING_OUTER_HALF - RING_BAR_HALF_WIDTH
    z = max(pose[2, 3], 0.013)
    best = None
    for axis_local in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        for sign in (1.0, -1.0):
            axis = pose[:3, :3] @ axis_local
            centre = pose[:3, 3] + sign * bar * axis
            clearance = np.inf
            for j, other in enumerate(sim.scene.objects):
                if j == ring:
                    continue
                xy = sim.object_pose(j)[:2, 3]
                radius = object_geometry(other.name).footprint_radius
                for s in (-1.0, 1.0):
                    finger = centre[:2] + s * FINGER_REACH * axis[:2]
                    clearance = min(clearance, float(np.linalg.norm(finger - xy)) - radius)
            # Prefer bars nearer the robot when clearances are similar (2 cm buckets).
            key = (round(clearance / 0.02), -float(np.linalg.norm(centre[:2])))
            if best is None or key > best[0]:
                yaw = float(np.arctan2(axis[1], axis[0]))
                best = (key, top_down_pose(np.array([centre[0], centre[1], z]), yaw))
    assert best is not None  # a ring has four bars
    return best[1]


@register_task
class InsertPeg(Task):
    name = "insert_peg"
    templates = ("put the ring on the {target}", "slide the ring onto the {target}")
    categories = ("peg",)
    destination = DESTINATION_X  # the peg X: the ring goes around it
    seed_salt = 7
    fixtures = (("ring", RING),)
    held_role = "ring"  # the ring is what the gripper carries, not the instruction's X
    distractors = NUM_DISTRACTORS

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        ring_i, peg_i = instance.info["ring"], instance.info["target"]
        if ring_i in sim.held_objects():
            return False
        ring, peg = sim.object_pose(ring_i), sim.object_pose(peg_i)
        local = ring[:3, :3].T @ (peg[:3, 3] - ring[:3, 3])
        hole = RING_OUTER_HALF - 2 * RING_BAR_HALF_WIDTH
        around = bool(np.all(np.abs(local[:2]) < hole))
        peg_top = peg[2, 3] + PEG_HALF[2]
        return bool(around and ring[2, 3] - RING_HALF_HEIGHT < peg_top - 0.02)

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        peg = sim.object_pose(instance.info["target"])
        grasp = ring_grasp(sim, instance.info["ring"])
        yield from pick_and_place(sim, instance.info["ring"], peg[:2, 3], peg[2, 3] + PEG_HALF[2] + DROP_ABOVE_PEG,
                                  grasp=grasp, align_origin=True)
