"""take_off_pan: "take the X off the frypan" (X a grocery lying in the pan).

Stands in for RLBench's meat-off-grill. LIBERO's ``chefmate_8_frypan`` is fixed to the table with its
handle pointing away from the robot; X lies in the pan. The expert lifts X out and puts it on the table
beside the pan. Success = X released on the table (bottom below ``TABLE_CONTACT``) with its centre
outside the pan's rim circle.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.scene import PlacedObject, SceneSpec
from abm.sim.tasks.base import Task, TaskInstance, pick_and_place, register_task, resting_on, sample_layout
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

NUM_DISTRACTORS = 2
PAN = "frypan"
PAN_CENTRE = (0.007, 0.0)      # m, bowl centre in the pan's body frame
PAN_RIM_RADIUS = 0.10          # m, outer radius of the bowl
PAN_FLOOR = 0.014              # m, height of the pan floor above the table
HANDLE_CENTRE = 0.18           # m, keep-out circle on the handle, along the pan's +x
HANDLE_RADIUS = 0.08
PAN_X = (0.42, 0.5)
PAN_Y = (-0.14, 0.14)
PAN_YAW = 0.35                 # rad, |yaw| of the handle about +x
DROP_DISTANCE = 0.2            # m from the bowl centre to where the expert puts X
TABLE_CONTACT = 0.012          # m


def _bowl_centre(pose: np.ndarray) -> np.ndarray:
    centre: np.ndarray = pose[:2, :2] @ np.asarray(PAN_CENTRE) + pose[:2, 3]
    return centre


@register_task
class TakeOffPan(Task):
    name = "take_off_pan"
    templates = ("take the {target} off the frypan", "remove the {target} from the frypan")
    categories = ("grocery",)
    destination = None  # X goes onto the free table beside the pan
    seed_salt = 8
    distractors = NUM_DISTRACTORS

    def sample(self, seed: int, split: str) -> TaskInstance:
        rng = self.rng(seed)
        target, variation, others = self.pick_target(rng, split)
        distractors = self.pick_distractors(rng, split, others)
        x, y, yaw = rng.uniform(*PAN_X), rng.uniform(*PAN_Y), rng.uniform(-PAN_YAW, PAN_YAW)
        pan = PlacedObject(PAN, float(x), float(y), float(yaw))
        c, s = np.cos(yaw), np.sin(yaw)
        bowl = np.array([x, y]) + np.array([[c, -s], [s, c]]) @ np.asarray(PAN_CENTRE)
        handle = bowl + HANDLE_CENTRE * np.array([c, s])
        food = PlacedObject(target, float(bowl[0]), float(bowl[1]), float(rng.uniform(-np.pi, np.pi)),
                            z=PAN_FLOOR - object_geometry(target).lower[2] + 0.002)
        obstacles = [(float(bowl[0]), float(bowl[1]), PAN_RIM_RADIUS),
                     (float(handle[0]), float(handle[1]), HANDLE_RADIUS)]
        region = ((0.3, 0.7), (-0.38, 0.38))
        rest = sample_layout(rng, distractors, obstacles=obstacles, region=region)
        return TaskInstance(self.name, split, seed, variation, self.instruction(target),
                            SceneSpec([pan, food, *rest]), [target], {"target": 1, "pan": 0})

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        target = instance.info["target"]
        bowl = _bowl_centre(sim.object_pose(instance.info["pan"]))
        outside = np.hypot(*(sim.object_pose(target)[:2, 3] - bowl)) > PAN_RIM_RADIUS + 0.01
        return bool(outside and resting_on(sim, target, max_bottom=TABLE_CONTACT))

    @staticmethod
    def drop_point(sim: Simulation, instance: TaskInstance) -> np.ndarray:
        """``(2,)`` free table spot beside the pan, farthest from the other objects (world, m)."""
        pan = sim.object_pose(instance.info["pan"])
        bowl = _bowl_centre(pan)
        handle_dir = np.arctan2(pan[1, 0], pan[0, 0])
        best, best_clear = None, -np.inf
        for angle in handle_dir + np.radians(np.arange(60, 301, 15)):
            point = bowl + DROP_DISTANCE * np.array([np.cos(angle), np.sin(angle)])
            if not (0.3 < point[0] < 0.7 and abs(point[1]) < 0.42):
                continue
            clear = min((np.hypot(*(sim.object_pose(j)[:2, 3] - point)) - object_geometry(o.name).footprint_radius
                         for j, o in enumerate(sim.scene.objects)
                         if j not in (instance.info["pan"], instance.info["target"])), default=1.0)
            if clear > best_clear:
                best, best_clear = point, clear
        if best is None:  # the angles always leave a spot on the table: a bug if not
            raise RuntimeError(f"no table spot beside the pan at {bowl.round(3).tolist()}")
        return best

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        yield from pick_and_place(sim, instance.info["target"], self.drop_point(sim, instance), 0.0)
