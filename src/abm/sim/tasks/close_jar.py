"""close_jar: "close the X jar" (X a colour; the instruction's target is "X jar").

Procedural coloured jars are fixed to the table; a grey lid with a dark bar handle (6.4 cm x 1.2 cm, see
:data:`abm.sim.props.LID_HANDLE_HALF`) lies on the table at a random yaw. The expert grasps the handle across
its width, so its grasp yaw follows the handle (which the policy's 64² views resolve, 4 pixels long), and
puts the lid on the named jar. Success = the lid is released, lies flat (tilt < ``MAX_TILT_DEG``) on top of
the named jar, centred within ``MAX_OFFSET``.

Version 2 of the task (:data:`abm.types.TASK_DATA_VERSIONS`): version 1's lid had a 1.6 cm square knob (one
pixel of the views) grasped with a four-fold symmetric label, so its approach yaw could not be read.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import catalog_entry, object_geometry
from abm.sim.props import JAR_HALF_HEIGHT
from abm.sim.tasks.base import DESTINATION_X, Task, TaskInstance, pick_and_place, register_task, top_down_pose
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2          # other jars of the split
MAX_OFFSET = 0.015           # m, lid centre to jar axis
MAX_TILT_DEG = 15.0
LID = "jar lid"


def handle_grasp(sim: Simulation, index: int) -> np.ndarray:
    """``(4, 4)`` top-down TCP pose grasping the lid ``index`` across its bar handle.

    The handle lies along the lid's local x axis, so the fingers close along the lid's local y axis (the
    finger yaw is the lid's yaw + 90 degrees, canonicalised within ±90 degrees of the reference yaw by
    :func:`top_down_pose`); the TCP is over the lid's centre at ``grasp_height`` (m) above its bottom.
    """
    pose = sim.object_pose(index)
    across = pose[:3, 1]
    bottom = pose[2, 3] + object_geometry(LID).lower[2]
    height = catalog_entry(LID).grasp_height
    assert height is not None  # set in the catalog: the handle's mid-height
    position = np.array([pose[0, 3], pose[1, 3], bottom + height])
    return top_down_pose(position, float(np.arctan2(across[1], across[0])))


@register_task
class CloseJar(Task):
    name = "close_jar"
    templates = ("close the {target}", "put the lid on the {target}")
    categories = ("jar",)
    destination = DESTINATION_X  # the jar X: the lid goes onto it
    seed_salt = 6
    fixtures = (("lid", LID),)
    held_role = "lid"  # the lid is what the gripper carries, not the instruction's X
    distractors = NUM_DISTRACTORS

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        lid_i, jar_i = instance.info["lid"], instance.info["target"]
        if lid_i in sim.held_objects():
            return False
        lid, jar = sim.object_pose(lid_i), sim.object_pose(jar_i)
        offset = np.hypot(*(lid[:2, 3] - jar[:2, 3]))
        tilt = np.degrees(np.arccos(np.clip(lid[2, 2], -1.0, 1.0)))
        lid_bottom = lid[2, 3] + object_geometry(LID).lower[2]
        jar_top = jar[2, 3] + JAR_HALF_HEIGHT
        return bool(offset < MAX_OFFSET and tilt < MAX_TILT_DEG and abs(lid_bottom - jar_top) < 0.01)

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        jar = sim.object_pose(instance.info["target"])
        lid = instance.info["lid"]
        yield from pick_and_place(sim, lid, jar[:2, 3], jar[2, 3] + JAR_HALF_HEIGHT,
                                  grasp=handle_grasp(sim, lid), align_origin=True)
