"""place_food: "put the X in the plate" (X a grocery)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, resting_on
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

PLATE_RADIUS = 0.065     # m, success if the food's centre is this close to the plate centre
PLATE_SURFACE = 0.006    # m, plate floor height above the table
NUM_DISTRACTORS = 2


@register_task
class PlaceFood(Task):
    name = "place_food"
    templates = ("put the {target} in the plate", "place the {target} on the plate")
    categories = ("grocery",)
    destination = "plate"
    seed_salt = 1
    fixtures = (("plate", "plate"),)
    distractors = NUM_DISTRACTORS

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        target, plate = instance.info["target"], instance.info["plate"]
        t, p = sim.object_pose(target), sim.object_pose(plate)
        close = np.hypot(*(t[:2, 3] - p[:2, 3])) < PLATE_RADIUS
        return bool(close and resting_on(sim, target, max_bottom=0.04))

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        plate = sim.object_pose(instance.info["plate"])
        yield from pick_and_place(sim, instance.info["target"], plate[:2, 3], PLATE_SURFACE)
