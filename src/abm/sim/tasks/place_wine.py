"""place_wine: "put the X in the wine rack" (X a bottle; the wine bottle is seen, other bottles unseen).

The rack (procedural, fixed to the table) has three upright slots; success = the bottle stands upright
in any slot and is released.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import RACK_SLOT_PITCH, catalog_entry, rack_slot_offsets
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, resting_on
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2
MAX_TILT_DEG = 20.0


@register_task
class PlaceWine(Task):
    name = "place_wine"
    templates = ("put the {target} in the wine rack", "place the {target} in the wine rack")
    categories = ("bottle",)
    destination = "wine rack"  # any of its slots
    seed_salt = 3
    fixtures = (("rack", "wine rack"),)
    distractors = 0
    borrowed_distractors = (("place_food", NUM_DISTRACTORS),)  # groceries of the same split
    fixed_yaw = {"wine rack": (-0.35, 0.35)}

    @staticmethod
    def slot_positions(sim: Simulation, rack_index: int) -> np.ndarray:
        """``(num_slots, 3)`` slot centres on the rack floor (world)."""
        rack = sim.object_pose(rack_index)
        size = catalog_entry("wine rack").size
        local = np.concatenate([rack_slot_offsets(), np.full((len(rack_slot_offsets()), 1), -size[2])], 1)
        slots: np.ndarray = local @ rack[:3, :3].T + rack[:3, 3]
        return slots

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        bottle_i, rack_i = instance.info["target"], instance.info["rack"]
        bottle, rack = sim.object_pose(bottle_i), sim.object_pose(rack_i)
        local = rack[:3, :3].T @ (bottle[:3, 3] - rack[:3, 3])
        size = catalog_entry("wine rack").size
        offsets = rack_slot_offsets()
        in_slot = any(abs(local[0] - ox) < size[0] and abs(local[1] - oy) < RACK_SLOT_PITCH / 2
                      for ox, oy in offsets)
        tilt = np.degrees(np.arccos(np.clip(bottle[2, 2], -1.0, 1.0)))
        return bool(in_slot and tilt < MAX_TILT_DEG and resting_on(sim, bottle_i, max_bottom=0.03))

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        bottle = sim.object_pose(instance.info["target"])
        slots = self.slot_positions(sim, instance.info["rack"])
        slot = slots[int(np.argmin(np.linalg.norm(slots[:, :2] - bottle[:2, 3], axis=1)))]
        floor = float(slot[2]) + 0.012
        rack = sim.object_pose(instance.info["rack"])
        # Fingers close along the rack's long axis, where the slot is widest for the open fingers.
        rack_x_yaw = float(np.arctan2(rack[1, 0], rack[0, 0]))
        yield from pick_and_place(sim, instance.info["target"], slot[:2], floor, place_yaw=rack_x_yaw)
