"""pick_block: "put the X block on the target" (X a colour)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import catalog_entry
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, resting_on
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2


@register_task
class PickBlock(Task):
    name = "pick_block"
    templates = ("put the {target} on the target", "stack the {target} on the target")
    categories = ("block",)
    destination = "target"  # the target pad
    seed_salt = 2
    fixtures = (("goal", "target"),)  # the flat target pad the block goes on
    distractors = NUM_DISTRACTORS

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        block, goal = instance.info["target"], instance.info["goal"]
        b, g = sim.object_pose(block), sim.object_pose(goal)
        half = catalog_entry("target").size[0]
        local = g[:3, :3].T @ (b[:3, 3] - g[:3, 3])
        inside = bool(np.all(np.abs(local[:2]) < half))
        return inside and resting_on(sim, block, max_bottom=0.02)

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        goal = sim.object_pose(instance.info["goal"])
        surface = 2 * catalog_entry("target").size[2]
        yield from pick_and_place(sim, instance.info["target"], goal[:2, 3], surface)
