"""Compositional evaluation-only tasks: a trained skill applied to the objects of another task.

* ``place_block_in_plate``: "put the X block in the plate" -- place_food's skill, pick_block's objects.
* ``pick_food_to_target``: "put the X on the target" -- pick_block's skill, place_food's objects.

Both reuse the trained tasks' instruction templates (so the instruction decomposition maps them onto
the trained skills), predicates and experts; their objects live under the ``compositional`` split only
and they are never offered for demonstration generation (:attr:`Task.evaluation_only`).
"""

from __future__ import annotations

from abm.sim.tasks.base import register_task
from abm.sim.tasks.pick_block import PickBlock
from abm.sim.tasks.place_food import PlaceFood


@register_task
class PlaceBlockInPlate(PlaceFood):
    name = "place_block_in_plate"
    categories = ("block",)
    evaluation_only = True
    seed_salt = 9


@register_task
class PickFoodToTarget(PickBlock):
    name = "pick_food_to_target"
    categories = ("grocery",)
    evaluation_only = True
    seed_salt = 10
