"""close_jar: "close the X jar" (X a colour; the instruction's target is "X jar").

Procedural coloured jars are fixed to the table; a grey lid with a knob lies on the table. The expert
grasps the knob and puts the lid on the named jar. Success = the lid is released, lies flat (tilt
< ``MAX_TILT_DEG``) on top of the named jar, centred within ``MAX_OFFSET``.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.props import JAR_HALF_HEIGHT
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task
from abm.types import KeyframeAction

NUM_DISTRACTORS = 2          # other jars of the split
MAX_OFFSET = 0.015           # m, lid centre to jar axis
MAX_TILT_DEG = 15.0
LID = "jar lid"


@register_task
class CloseJar(Task):
    name = "close_jar"
    templates = ("close the {target}", "put the lid on the {target}")
    categories = ("jar",)
    seed_salt = 6
    fixtures = (("lid", LID),)
    distractors = NUM_DISTRACTORS

    def success(self, sim, instance: TaskInstance) -> bool:
        lid_i, jar_i = instance.info["lid"], instance.info["target"]
        if lid_i in sim.held_objects():
            return False
        lid, jar = sim.object_pose(lid_i), sim.object_pose(jar_i)
        offset = np.hypot(*(lid[:2, 3] - jar[:2, 3]))
        tilt = np.degrees(np.arccos(np.clip(lid[2, 2], -1.0, 1.0)))
        lid_bottom = lid[2, 3] + object_geometry(LID).lower[2]
        jar_top = jar[2, 3] + JAR_HALF_HEIGHT
        return bool(offset < MAX_OFFSET and tilt < MAX_TILT_DEG and abs(lid_bottom - jar_top) < 0.01)

    def expert(self, sim, instance: TaskInstance) -> Iterator[KeyframeAction]:
        jar = sim.object_pose(instance.info["target"])
        yield from pick_and_place(sim, instance.info["lid"], jar[:2, 3], jar[2, 3] + JAR_HALF_HEIGHT,
                                  align_origin=True)
