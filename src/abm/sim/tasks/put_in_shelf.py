"""put_in_shelf: "put the X on the top shelf" / "put the X on the bottom shelf" (X a grocery).

Stands in for RLBench's put-in-safe. The shelf (procedural, fixed, :func:`abm.sim.props.build_shelf`) is
stepped: the bottom shelf faces the robot and the top shelf is behind it, so a top-down gripper reaches
both. Success = X released with its centre over the named shelf and its bottom on that shelf's surface.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.props import SHELF_BOTTOM_Z, SHELF_HALF_WIDTH, SHELF_TIER_DEPTH, SHELF_TOP_Z
from abm.sim.scene import PlacedObject, SceneSpec
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, resting_on, sample_layout
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2
SHELF_X = (0.5, 0.56)          # m, range of the shelf origin
SHELF_Y = (0.14, 0.22)         # m, |y| range of the shelf origin (the side is random)
SHELF_YAW_JITTER = 0.2         # rad around facing the robot
EDGE_MARGIN = 0.01             # m, the object centre must be this far inside the shelf's edges
LEVELS = {"top": SHELF_TOP_Z, "bottom": SHELF_BOTTOM_Z}


@register_task
class PutInShelf(Task):
    name = "put_in_shelf"
    templates = ("put the {target} on the top shelf", "put the {target} on the bottom shelf")
    categories = ("grocery",)
    destination = "shelf"  # the named tier is one part of it
    seed_salt = 4
    distractors = NUM_DISTRACTORS

    def sample(self, seed: int, split: str) -> TaskInstance:
        rng = self.rng(seed)
        target, variation, others = self.pick_target(rng, split)
        level = "top" if rng.random() < 0.5 else "bottom"
        distractors = self.pick_distractors(rng, split, others)
        side = 1.0 if rng.random() < 0.5 else -1.0
        sx, sy = rng.uniform(*SHELF_X), side * rng.uniform(*SHELF_Y)
        yaw = float(np.arctan2(sy, sx) + rng.uniform(-SHELF_YAW_JITTER, SHELF_YAW_JITTER))
        shelf = PlacedObject("shelf", float(sx), float(sy), yaw)
        # Keep-out circles over the two shelves.
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        radius = float(np.hypot(SHELF_TIER_DEPTH / 2, SHELF_HALF_WIDTH))
        obstacles = [(*(np.array([sx, sy]) + sign * SHELF_TIER_DEPTH / 2 * axis), radius) for sign in (-1, 1)]
        region = ((0.3, 0.66), (-0.42, 0.42))
        objects = sample_layout(rng, [target, *distractors], obstacles=obstacles, region=region)
        instruction = self.templates[0 if level == "top" else 1].format(target=target)
        return TaskInstance(self.name, split, seed, variation, instruction, SceneSpec([shelf, *objects]),
                            [target], {"target": 1, "shelf": 0, "level": level})

    @staticmethod
    def shelf_centre(sim: Simulation, shelf_index: int, level: str) -> np.ndarray:
        """``(3,)`` centre of a shelf's surface (world, m)."""
        pose = sim.object_pose(shelf_index)
        local = np.array([SHELF_TIER_DEPTH / 2 * (1 if level == "top" else -1), 0.0, LEVELS[level]])
        centre: np.ndarray = pose[:3, :3] @ local + pose[:3, 3]
        return centre

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        target, level = instance.info["target"], instance.info["level"]
        shelf = sim.object_pose(instance.info["shelf"])
        obj = sim.object_pose(target)
        centre = obj[:3, :3] @ object_geometry(sim.scene.objects[target].name).center + obj[:3, 3]
        local = shelf[:3, :3].T @ (centre - shelf[:3, 3])
        depth = local[0] if level == "top" else -local[0]
        inside = EDGE_MARGIN < depth < SHELF_TIER_DEPTH - EDGE_MARGIN and \
            abs(local[1]) < SHELF_HALF_WIDTH - EDGE_MARGIN
        bottom = obj[2, 3] + object_geometry(sim.scene.objects[target].name).lower[2]
        on_level = bool(bottom > LEVELS[level] - 0.01)
        return bool(inside and on_level and resting_on(sim, target, max_bottom=LEVELS[level] + 0.02))

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        level = instance.info["level"]
        shelf = sim.object_pose(instance.info["shelf"])
        goal = self.shelf_centre(sim, instance.info["shelf"], level)
        # Fingers along the shelf's width so that the hand stays clear of the top shelf's edge.
        width_yaw = float(np.arctan2(shelf[1, 1], shelf[0, 1]))
        yield from pick_and_place(sim, instance.info["target"], goal[:2], LEVELS[level], place_yaw=width_yaw)
