"""put_in_container: "put the X in the Y" -- X a grocery or a block, Y one of several containers.

The first ABM-Bench task whose instruction names two objects (GitHub issue 14, "several targets per
instruction"). Both vary per episode: X comes from the split's object list, Y from the split's
``containers`` list (a second slot of the split file, see :mod:`abm.sim.splits`). The scene holds Y, a
second container of the same split as a distractor (so grounding Y matters), X and two other objects
of X's list. Instructions parse with the two-target skill ``put X in Y`` of
``abm/language/templates.yaml`` (the parser's ``target`` is X, its ``second`` Y). The plate is not a
container here: "put the X in the plate" is place_food's more specific one-target skill.

Roles: ``info["target"]`` and ``info["container"]`` are the object indices of X and Y, and
``target_names == [X, Y]`` (so ``Episode.target_names`` lists X first, Y second). The expert labels
each keyframe with its sub-goal (:meth:`PutInContainer.keyframe_subgoal`): approach, grasp and lift
work on X (sub-goal 0 = ``target_names[0]``), move, place and retreat on Y (sub-goal 1 =
``target_names[1]``); :func:`abm.sim.env.run_expert` stores them as ``metadata["subgoals"]``.

Pairing rule (which (X, Y) pairs each split draws). Let ``S_X`` and ``S_Y`` be the task's ``seen``
object and container lists in the split file's order. Seen object ``S_X[i]`` is *held out* with seen
container ``S_Y[i mod len(S_Y)]``: that pair never appears in the ``seen`` split (nor in any other
split but ``compositional``), and the ``compositional`` split draws only held-out pairs (of its own
lists). So every seen object is trained with every seen container but one, every seen container with
most seen objects, and the compositional split tests combinations never demonstrated together. The
split-file check (:meth:`PutInContainer.check_splits`) also refuses a held-out pair that another
trainable task demonstrates (e.g. place_food's seen groceries in the plate, for a split file that makes
the plate a container).

Success: X not held, its centre inside Y's opening (a circle for the plates and the bowl, Y's box
otherwise, ``WALL_MARGIN`` inside the collision outline) and its lowest point below Y's rim. The expert
picks X top-down and releases it over Y's centre as low as it can with the fingertips 1 cm above Y's rim
(:meth:`PutInContainer.release_surface`), so the hand never enters a container (the baskets are 11.7 cm
high) and a tall X (the bbq sauce bottle) is not dropped from the rim's height, where it could tip out.
The layout keeps extra room around containers that rise above the hand's underside at a grasp
(:meth:`PutInContainer.layout`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from abm.sim.catalog import object_geometry
from abm.sim.scene import PlacedObject, SceneSpec
from abm.sim.tasks.base import (
    DESTINATION_Y,
    TASKS,
    Task,
    TaskInstance,
    grasp_pose,
    pick_and_place,
    register_task,
    sample_layout,
)
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation
    from abm.sim.split_file import ObjectSplits

SLOT = "containers"               # split-file key of the second slot
NUM_DISTRACTORS = 2               # other objects of X's split list
NUM_CONTAINER_DISTRACTORS = 1     # other containers of the split
WALL_MARGIN = 0.005               # m, success region inset from the container's collision outline
TALL_RIM = 0.05                   # m, containers higher than this reach the hand when it grasps beside them
HAND_CLEARANCE = 0.045            # m, extra free space between a tall container and the other objects
LAYOUT_TRIES = 20                 # container layouts tried before giving up
FINGERTIP_BELOW_TCP = 0.01        # m, the Panda's fingertips below its TCP
FLOOR_CLEARANCE = 0.012           # m, lowest support height the expert releases X over (above every floor)
ROUND_CONTAINERS = frozenset({"plate", "yellow plate", "white bowl"})
TARGET_SUBGOAL_KINDS = frozenset({"approach", "grasp", "lift"})      # sub-goal 0: X
CONTAINER_SUBGOAL_KINDS = frozenset({"move", "place", "retreat"})    # sub-goal 1: Y
COMPOSITIONAL = "compositional"


def held_out_pairs(splits: ObjectSplits, task: str = "put_in_container") -> set[tuple[str, str]]:
    """The (object, container) pairs the pairing rule keeps out of training (see the module docstring).

    Args:
        splits: a loaded :class:`abm.sim.splits.ObjectSplits`.
        task: the task whose ``seen`` lists define the rule.
    """
    objects = splits.tasks.get(task, {}).get("seen", [])
    containers = splits.slots.get(task, {}).get(SLOT, {}).get("seen", [])
    if not objects or not containers:
        return set()
    return {(x, containers[i % len(containers)]) for i, x in enumerate(objects)}


def split_pairs(splits: ObjectSplits, split: str, task: str = "put_in_container") -> list[tuple[str, str]]:
    """The (object, container) pairs a split draws from, in list order (objects outer, containers inner).

    ``compositional``: only held-out pairs of its lists; any other split: every pair of its lists except
    the held-out ones.
    """
    held = held_out_pairs(splits, task)
    objects = splits.objects(task, split)
    containers = splits.slot_objects(task, SLOT, split)
    want_held = split == COMPOSITIONAL
    return [(x, y) for x in objects for y in containers if ((x, y) in held) == want_held]


def _pairs_trained_elsewhere(splits: ObjectSplits, pairs: set[tuple[str, str]], task: str
                             ) -> list[tuple[str, str, str]]:
    """``(object, container, other task)`` for each pair another trainable task demonstrates: the
    container is one of that task's fixtures and the object is in its ``seen`` list."""
    found = []
    for name, cls in TASKS.items():
        if name == task or cls.evaluation_only:
            continue
        fixtures = {obj for _, obj in cls.fixtures}
        seen = set(splits.tasks.get(name, {}).get("seen", []))
        found += [(x, y, name) for x, y in sorted(pairs) if y in fixtures and x in seen]
    return found


@register_task
class PutInContainer(Task):
    name = "put_in_container"
    templates = (
        "put the {target} in the {container}",
        "place the {target} into the {container}",
        "drop the {target} in the {container}",
    )
    categories = ("grocery", "block")
    destination = DESTINATION_Y  # the container Y
    slots = {SLOT: ("container",)}
    seed_salt = 11
    distractors = NUM_DISTRACTORS

    # --- splits ----------------------------------------------------------------------------------
    @classmethod
    def check_splits(cls, splits: ObjectSplits) -> str | None:
        """Every split has pairs to draw, and no held-out pair is demonstrated by another task."""
        for split in splits.tasks.get(cls.name, {}):
            if not split_pairs(splits, split, cls.name):
                rule = ("its lists hold no held-out pair (seen object i with seen container i mod "
                        "len(containers))" if split == COMPOSITIONAL else "every pair of its lists is held out")
                return f"split {split!r} has no (object, container) pair to draw: {rule}"
        clashes = _pairs_trained_elsewhere(splits, held_out_pairs(splits, cls.name), cls.name)
        if clashes:
            listed = ", ".join(f"{x} in the {y} ({t})" for x, y, t in clashes)
            return (f"held-out (compositional) pairs are demonstrated by other tasks: {listed}; reorder the "
                    "seen lists so that the held-out pairs (seen object i, seen container i mod "
                    "len(containers)) are never trained")
        return None

    def containers(self, split: str) -> list[str]:
        """Containers (Y) of one split."""
        return self.splits.slot_objects(self.name, SLOT, split)

    def pairs(self, split: str) -> list[tuple[str, str]]:
        """The (X, Y) pairs ``split`` draws from (see :func:`split_pairs`)."""
        return split_pairs(self.splits, split, self.name)

    def held_out(self) -> set[tuple[str, str]]:
        """The (X, Y) pairs never drawn outside the compositional split."""
        return held_out_pairs(self.splits, self.name)

    # --- scene -----------------------------------------------------------------------------------
    def instruction_for(self, target: str, container: str, template: int = 0) -> str:
        """The instruction of template number ``template`` for object ``target`` and ``container``."""
        return self.templates[template].format(target=target, container=container)

    def sample(self, seed: int, split: str) -> TaskInstance:
        """Seeded scene: Y, a distractor container, X and two other objects; a random template.

        ``variation`` is the index of (X, Y) in :meth:`pairs`; ``info`` maps ``"container"`` (Y),
        ``"target"`` (X) and ``"distractor_containers"`` (a list) to object indices.
        """
        rng = self.rng(seed)
        pairs = self.pairs(split)
        variation = int(rng.integers(len(pairs)))
        target, container = pairs[variation]
        others = [n for n in self.objects(split) if n != target]
        distractors = self.pick_distractors(rng, split, others)
        spare = [c for c in self.containers(split) if c != container]
        count = min(NUM_CONTAINER_DISTRACTORS, len(spare))
        extra = [str(c) for c in rng.choice(spare, size=count, replace=False)] if count else []
        objects = self.layout(rng, [container, *extra], [target, *distractors])
        template = int(rng.integers(len(self.templates)))
        info = {"container": 0, "target": 1 + len(extra),
                "distractor_containers": list(range(1, 1 + len(extra)))}
        return TaskInstance(self.name, split, seed, variation, self.instruction_for(target, container, template),
                            SceneSpec(objects), [target, container], info)

    @staticmethod
    def layout(rng: np.random.Generator, containers: list[str], objects: list[str]) -> list[PlacedObject]:
        """Containers first, then the other objects clear of them on the table (containers, then objects).

        A container higher than ``TALL_RIM`` keeps ``HAND_CLEARANCE`` more free space around it: the hand
        (about 20 cm across the fingers, its underside about 4 cm above the fingertips) grasping an object beside
        a basket would otherwise hit the basket's rim.
        """
        for _ in range(LAYOUT_TRIES):
            placed = sample_layout(rng, containers)
            obstacles = []
            for obj in placed:
                geo = object_geometry(obj.name)
                extra = HAND_CLEARANCE if geo.height > TALL_RIM else 0.0
                obstacles.append((obj.x, obj.y, geo.footprint_radius + extra))
            try:
                return placed + sample_layout(rng, objects, obstacles=obstacles, max_tries=100)
            except RuntimeError:
                continue
        raise RuntimeError(f"could not place {containers + objects} on the table without overlap")

    # --- success and expert ----------------------------------------------------------------------
    @staticmethod
    def opening(sim: Simulation, index: int) -> tuple[np.ndarray, np.ndarray, float]:
        """``(centre (2,), rotation (2, 2), rim height)`` of container ``index``: its collision box centre
        in the world (m), its horizontal axes, and the height of its top above the table (m)."""
        geo = object_geometry(sim.scene.objects[index].name)
        pose = sim.object_pose(index)
        centre = pose[:3, :3] @ geo.center + pose[:3, 3]
        return centre[:2], pose[:2, :2], float(pose[2, 3] + geo.upper[2])

    @staticmethod
    def lowest_point(sim: Simulation, index: int) -> float:
        """World height (m) of the lowest corner of object ``index``'s collision box, in any orientation."""
        geo = object_geometry(sim.scene.objects[index].name)
        pose = sim.object_pose(index)
        corners = np.array(np.meshgrid(*zip(geo.lower, geo.upper, strict=True))).reshape(3, -1).T
        return float((corners @ pose[:3, :3].T + pose[:3, 3])[:, 2].min())

    def inside(self, sim: Simulation, target: int, container: int) -> bool:
        """Whether object ``target`` lies in ``container``'s opening, below its rim (holding not checked)."""
        name = sim.scene.objects[container].name
        geo = object_geometry(name)
        centre, rot, rim = self.opening(sim, container)
        t_geo = object_geometry(sim.scene.objects[target].name)
        t_pose = sim.object_pose(target)
        t_centre = (t_pose[:3, :3] @ t_geo.center + t_pose[:3, 3])[:2]
        local = rot.T @ (t_centre - centre)
        half = (np.asarray(geo.upper[:2]) - np.asarray(geo.lower[:2])) / 2 - WALL_MARGIN
        if name in ROUND_CONTAINERS:
            within = float(np.hypot(*local)) < float(half.min())
        else:
            within = bool(np.all(np.abs(local) < half))
        return bool(within and self.lowest_point(sim, target) < rim)

    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        target, container = instance.info["target"], instance.info["container"]
        if target in sim.held_objects():
            return False
        return self.inside(sim, target, container)

    def release_surface(self, sim: Simulation, target: int, rim: float) -> float:
        """Height (m) to pass to :func:`pick_and_place` as the support surface: X is released
        ``DROP_HEIGHT`` above it, as low as possible with the fingertips still ``DROP_HEIGHT`` above the
        rim (the hand never enters the container), but the surface no lower than ``FLOOR_CLEARANCE`` (above
        every container's floor)."""
        hang = float(grasp_pose(sim, target)[2, 3]) - self.lowest_point(sim, target)  # X's bottom below the TCP
        return max(FLOOR_CLEARANCE, rim + FINGERTIP_BELOW_TCP - hang)

    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        target = instance.info["target"]
        centre, _, rim = self.opening(sim, instance.info["container"])
        yield from pick_and_place(sim, target, centre, self.release_surface(sim, target, rim))

    def keyframe_subgoal(self, action: KeyframeAction) -> int | None:
        """0 (X) for approach, grasp and lift; 1 (Y) for move, place and retreat; else ``None``."""
        if action.kind in TARGET_SUBGOAL_KINDS:
            return 0
        return 1 if action.kind in CONTAINER_SUBGOAL_KINDS else None
