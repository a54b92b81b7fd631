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
from abm.sim.scene import SceneSpec
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, sample_layout
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

    def sample(self, seed: int, split: str) -> TaskInstance:
        rng = np.random.default_rng([seed, 6])
        target, variation, others = self.pick_target(rng, split)
        count = min(NUM_DISTRACTORS, len(others))
        distractors = [str(n) for n in rng.choice(others, size=count, replace=False)]
        objects = sample_layout(rng, [LID, target, *distractors])
        return TaskInstance(self.name, split, seed, variation, self.instruction(target),
                            SceneSpec(objects), [target], {"target": 1, "lid": 0})

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
