"""Task interface, registry and shared helpers (layout sampling, top-down pick-and-place expert).

A task is one small class registered with :func:`register_task`. It declares:

* ``name``, ``templates`` (instruction templates with ``{target}``) and ``categories`` (catalog
  categories its split objects may belong to, checked when splits load);
* ``seed_salt``: the scene RNG is ``default_rng([seed, seed_salt])``;
* ``fixtures``: ``(role, catalog object)`` pairs placed before the target (a plate, the goal pad, a lid);
  the role names index the objects in :attr:`TaskInstance.info` (``info["target"]`` is the target);
* ``distractors``: how many other objects of the task's own split join the scene, and
  ``borrowed_distractors``: ``(task, count)`` objects taken from another task's split;
* ``fixed_yaw``: yaw ranges (rad) of objects that must face the robot;
* ``skills`` (optional): the instruction skills its templates use when the built-in ones
  (``abm/language/templates.yaml``) do not know their wording, in that file's form;
* ``slots`` (optional): a second object slot listed in the split file beside the targets, YAML key ->
  catalog categories (put_in_container: ``{"containers": ("container",)}``), checked when splits load,
  and :meth:`Task.check_splits` for a task's own checks of the whole split file;
* ``destination`` (optional): the object the task brings X to (the plate, the target pad, the rack; X itself
  for the jar a lid closes; ``None`` for none), grounded into the policy's second mask;
* ``held_role`` (optional): the role (key of :attr:`TaskInstance.info`) of the object the gripper must hold to
  do the task, ``"target"`` by default; insert_peg holds its ``"ring"``, close_jar its ``"lid"``
  (:meth:`Task.held_object`; evaluation's "grasp missed" / "timeout" labels check it);
* :meth:`Task.keyframe_subgoal` (optional): which object of ``target_names`` an expert keyframe works
  on, stored per keyframe in the episode metadata as ``"subgoals"`` by :func:`abm.sim.env.run_expert`;

and fills two methods: :meth:`Task.success` (predicate on the simulator state) and :meth:`Task.expert`
(scripted expert, a generator of :class:`abm.types.KeyframeAction` that may read the simulator between
keyframes). :meth:`Task.sample` does the rest; a task whose layout is not "fixtures, target, distractors
on the table" (a shelf placed first, food inside a pan) overrides it. See docs/benchmark.md for a
worked example.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from abm.geometry.rotations import GRIPPER_SYMMETRY, canonical_gripper_matrix, matrix_to_quat
from abm.registry import Registry
from abm.sim.catalog import catalog_entry, object_geometry
from abm.sim.scene import PlacedObject, SceneSpec
from abm.sim.split_file import ObjectSplits, read_splits
from abm.types import KeyframeAction

if TYPE_CHECKING:
    from abm.sim.simulation import Simulation

#: every task, by name (its class); filled by importing :mod:`abm.sim.tasks`, which imports every module of the
#: package (a task is one module with a :func:`register_task` class)
TASKS: Registry[type[Task]] = Registry("task")

# Table region where objects are placed (m, world frame).
TABLE_X = (0.33, 0.68)
TABLE_Y = (-0.3, 0.3)
OBJECT_GAP = 0.045          # m of free space between footprints
APPROACH_HEIGHT = 0.10      # m above the grasp / place pose
LIFT_HEIGHT = 0.15          # m lifted after grasping
DROP_HEIGHT = 0.01          # m above the support surface when releasing
FINGER_REACH = 0.06         # m from the TCP to the outside of an open finger
DESTINATION_X = "X"         # Task.destination: the instruction's X (the skill text's placeholder)
DESTINATION_Y = "Y"         # Task.destination: Y of a two-target instruction


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator adding a task to :data:`TASKS` under ``cls.name`` (``ValueError`` for a name registered
    twice)."""
    return TASKS.register(cls.name, cls)


@dataclass
class TaskInstance:
    """One sampled episode setup.

    Attributes:
        task, split, seed: identification.
        variation: index of the target object in the split's object list.
        instruction: the English instruction.
        scene: objects and their poses.
        target_names: objects the instruction refers to.
        info: task-specific data (e.g. which object is the goal), JSON-friendly.
    """

    task: str
    split: str
    seed: int
    variation: int
    instruction: str
    scene: SceneSpec
    target_names: list[str]
    info: dict[str, Any] = field(default_factory=dict)


class Task(ABC):
    """Base class of ABM-Bench tasks. Instances are stateless apart from the object splits."""

    name: ClassVar[str]
    templates: ClassVar[tuple[str, ...]]
    categories: ClassVar[tuple[str, ...]]
    seed_salt: ClassVar[int]
    fixtures: ClassVar[tuple[tuple[str, str], ...]] = ()
    distractors: ClassVar[int] = 2
    borrowed_distractors: ClassVar[tuple[tuple[str, int], ...]] = ()
    fixed_yaw: ClassVar[dict[str, tuple[float, float]]] = {}
    #: Evaluation-only tasks (the compositional ones) are never offered for demonstration generation.
    evaluation_only: ClassVar[bool] = False
    #: Second object slots: split-file key -> catalog categories of its objects (see abm.sim.splits).
    slots: ClassVar[dict[str, tuple[str, ...]]] = {}
    #: Skills of its own, when its instructions use a wording the built-in templates do not know: entries of
    #: ``abm/language/templates.yaml``'s form (``skill``, ``patterns``, ``examples``, ``places``), added to the
    #: instruction parser's (abm.language.instruction.load_templates).
    skills: ClassVar[tuple[dict[str, Any], ...]] = ()
    #: Where the task brings what it moves (the policy's second mask, :mod:`abm.grounding.conditioning`): a scene
    #: object's catalog name (``"plate"``, the ``"target"`` pad, ``"wine rack"``, ``"shelf"``, ``"plant"``),
    #: :data:`DESTINATION_X` (the instruction's X itself: the jar its lid closes, the peg the ring goes on),
    #: :data:`DESTINATION_Y` (Y of a two-target instruction), or ``None``: no object (X goes onto the free table).
    destination: ClassVar[str | None] = None
    #: The role (key of :attr:`TaskInstance.info`) of the object the gripper must hold: the instruction's target
    #: by default; insert_peg's ring, close_jar's lid (:meth:`held_object`).
    held_role: ClassVar[str] = "target"

    def __init__(self, splits: ObjectSplits | None = None) -> None:
        self.splits = splits if splits is not None else read_splits(None, TASKS)

    @classmethod
    def check_objects(cls, names: list[str]) -> str | None:
        """A problem description if ``names`` cannot be targets of this task, else ``None``."""
        bad = [n for n in names if catalog_entry(n).category not in cls.categories]
        if bad:
            return f"objects {bad} are not of the categories this task uses ({list(cls.categories)})"
        return None

    @classmethod
    def check_splits(cls, splits: ObjectSplits) -> str | None:
        """A problem with this task's lists in a loaded split file (:class:`abm.sim.splits.ObjectSplits`),
        else ``None``; called once every task's lists are read. The default has nothing to check."""
        return None

    @classmethod
    def destination_name(cls, targets: Sequence[str]) -> str | None:
        """The name of the destination object (:attr:`destination`) of an episode whose instruction names
        ``targets`` (``(X,)`` or ``(X, Y)``; the ground-truth ``target_names`` or the parsed descriptions)."""
        if cls.destination == DESTINATION_X:
            return targets[0] if targets else None
        if cls.destination == DESTINATION_Y:
            return targets[1] if len(targets) > 1 else None
        return cls.destination

    def held_object(self, instance: TaskInstance) -> int | None:
        """Scene index of the object the gripper must hold in ``instance`` (:attr:`held_role`), ``None`` when the
        instance does not name one."""
        index = instance.info.get(self.held_role)
        return None if index is None else int(index)

    def keyframe_subgoal(self, action: KeyframeAction) -> int | None:
        """Index into ``target_names`` of the object an expert keyframe works on, or ``None`` for a
        task without sub-goal labels (the default: its episodes carry no ``"subgoals"`` metadata)."""
        return None

    def objects(self, split: str) -> list[str]:
        return self.splits.objects(self.name, split)

    def instruction(self, target: str) -> str:
        """Instruction for a target (first template)."""
        return self.templates[0].format(target=target)

    def pick_target(self, rng: np.random.Generator, split: str) -> tuple[str, int, list[str]]:
        """``(target, variation, other objects of the split)`` for a seeded episode."""
        names = self.objects(split)
        variation = int(rng.integers(len(names)))
        return names[variation], variation, [n for i, n in enumerate(names) if i != variation]

    def rng(self, seed: int) -> np.random.Generator:
        """The scene RNG of ``seed``."""
        return np.random.default_rng([seed, self.seed_salt])

    def pick_distractors(self, rng: np.random.Generator, split: str, others: list[str]) -> list[str]:
        """``distractors`` of the split's other objects, then each ``borrowed_distractors`` entry."""
        names: list[str] = []
        if self.distractors:
            count = min(self.distractors, len(others))
            names += [str(n) for n in rng.choice(others, size=count, replace=False)]
        for task, wanted in self.borrowed_distractors:
            pool = self.splits.tasks.get(task, {}).get(split, [])
            names += [str(n) for n in rng.choice(pool, size=min(wanted, len(pool)), replace=False)]
        return names

    def roles(self) -> dict[str, int]:
        """Role name -> object index: the fixtures in order, then ``"target"``."""
        roles = {role: i for i, (role, _) in enumerate(self.fixtures)}
        roles["target"] = len(self.fixtures)
        return roles

    def sample(self, seed: int, split: str) -> TaskInstance:
        """Seeded, reproducible scene: fixtures, the target and the distractors, laid out on the table."""
        rng = self.rng(seed)
        target, variation, others = self.pick_target(rng, split)
        distractors = self.pick_distractors(rng, split, others)
        names = [obj for _, obj in self.fixtures] + [target, *distractors]
        objects = sample_layout(rng, names, fixed_yaw=dict(self.fixed_yaw) or None)
        return TaskInstance(self.name, split, seed, variation, self.instruction(target), SceneSpec(objects),
                            [target], self.roles())

    @abstractmethod
    def success(self, sim: Simulation, instance: TaskInstance) -> bool:
        """Whether the task is solved in the simulator's current state."""

    @abstractmethod
    def expert(self, sim: Simulation, instance: TaskInstance) -> Iterator[KeyframeAction]:
        """Scripted expert keyframes; reads ``sim`` between keyframes."""


# --- layout ----------------------------------------------------------------------------------------
def sample_layout(rng: np.random.Generator, names: list[str], fixed_yaw: dict[str, tuple[float, float]]
                  | None = None, max_tries: int = 500, obstacles: list[tuple[float, float, float]] | None = None,
                  region: tuple[tuple[float, float], tuple[float, float]] = (TABLE_X, TABLE_Y)
                  ) -> list[PlacedObject]:
    """Place objects at random non-overlapping table poses (first names first).

    Args:
        names: canonical names in placement order.
        fixed_yaw: optional name -> (low, high) yaw range in radians (default: any yaw).
        obstacles: ``(x, y, radius)`` circles (m) already occupied, e.g. by a large fixed object.
        region: ``((x_low, x_high), (y_low, y_high))`` table region for object centres (m).
    """
    fixed_yaw = fixed_yaw or {}
    (x_lo, x_hi), (y_lo, y_hi) = region
    for _ in range(50):
        placed: list[PlacedObject] = [PlacedObject("", x, y) for x, y, _ in obstacles or []]
        radii: list[float] = [r for _, _, r in obstacles or []]
        for name in names:
            radius = object_geometry(name).footprint_radius
            for _ in range(max_tries):
                x = rng.uniform(x_lo + 0.5 * radius, x_hi - 0.3 * radius)
                y = rng.uniform(y_lo + 0.3 * radius, y_hi - 0.3 * radius)
                if all(np.hypot(x - p.x, y - p.y) > radius + r + OBJECT_GAP
                       for p, r in zip(placed, radii, strict=True)):
                    lo, hi = fixed_yaw.get(name, (-np.pi, np.pi))
                    placed.append(PlacedObject(name, float(x), float(y), float(rng.uniform(lo, hi))))
                    radii.append(radius)
                    break
            else:
                break
        placed = placed[len(obstacles or []):]
        if len(placed) == len(names):
            return placed
    raise RuntimeError(f"could not place {names} on the table without overlap")


# --- grasping --------------------------------------------------------------------------------------
def top_down_pose(position: np.ndarray, finger_axis_yaw: float, symmetry: int = GRIPPER_SYMMETRY
                  ) -> np.ndarray:
    """``(4, 4)`` TCP pose pointing straight down with the fingers closing along ``finger_axis_yaw``.

    The orientation is the canonical member of its symmetry class (see
    :func:`abm.geometry.canonical_gripper_matrix`): with the default ``symmetry`` 2 the finger yaw is
    turned by 180 degrees if needed to lie within ±90 degrees of the reference yaw; 4 reduces it to
    ±45 degrees (square objects); 0 sets it to the reference (round objects).
    """
    axis = np.array([np.cos(finger_axis_yaw), np.sin(finger_axis_yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(axis, z)
    pose = np.eye(4)
    pose[:3, :3] = canonical_gripper_matrix(np.stack([x, axis, z], axis=1), symmetry)
    pose[:3, 3] = position
    return pose


def finger_yaw(pose: np.ndarray) -> float:
    """World yaw (rad) of a TCP pose's finger axis (its y axis)."""
    return float(np.arctan2(pose[1, 1], pose[0, 1]))


def action(pose: np.ndarray, gripper_open: bool, ignore_collision: bool, kind: str = "",
           symmetry: int = GRIPPER_SYMMETRY) -> KeyframeAction:
    """A keyframe at ``pose`` (4x4); ``kind`` and ``symmetry`` label it (see :class:`KeyframeAction`)."""
    return KeyframeAction(pose[:3, 3].copy(), matrix_to_quat(pose[:3, :3]), gripper_open, ignore_collision,
                          kind, symmetry)


def grasp_symmetry(name: str) -> int:
    """Symmetry order of a top-down grasp of object ``name`` (see :attr:`CatalogEntry.yaw_symmetry`)."""
    return catalog_entry(name).yaw_symmetry


def grasp_pose(sim: Simulation, index: int) -> np.ndarray:
    """Top-down grasp of object ``index`` at its grasp height, in the canonical yaw of its symmetry.

    Fingers close across the narrower horizontal side. A square footprint (symmetry 4) is grasped
    across whichever side puts the finger yaw within ±45 degrees of the reference, a round one
    (symmetry 0) at the reference yaw; so every demonstration of an object labels its grasp the same way.
    """
    name = sim.scene.objects[index].name
    geo = object_geometry(name)
    entry = catalog_entry(name)
    pose = sim.object_pose(index)
    center_local = geo.center
    ex, ey = geo.upper[0] - geo.lower[0], geo.upper[1] - geo.lower[1]
    center = pose[:3, :3] @ center_local + pose[:3, 3]
    local_axis = pose[:3, 0] if ex < ey else pose[:3, 1]
    yaw = float(np.arctan2(local_axis[1], local_axis[0]))
    bottom = pose[2, 3] + geo.lower[2]
    if entry.grasp_height is not None:
        z = bottom + entry.grasp_height
    else:
        z = max(bottom + geo.height - 0.02, bottom + 0.5 * geo.height)
    z = max(z, 0.013)
    return top_down_pose(np.array([center[0], center[1], z]), yaw, grasp_symmetry(name))


def pick_and_place(sim: Simulation, index: int, place_xy: np.ndarray, surface_z: float,
                   place_yaw: float | None = None, grasp: np.ndarray | None = None,
                   align_origin: bool = False) -> Iterator[KeyframeAction]:
    """Six RLBench-style keyframes: approach, grasp, lift, move, place (release), retreat.

    Args:
        index: object to pick.
        place_xy: ``(2,)`` where the object's grasp point should end up (m, world); with
            ``align_origin``, where the object's body origin should end up instead.
        surface_z: height of the support surface at the place location (m).
        place_yaw: finger-axis yaw when placing (default: as grasped); the place keyframes then carry
            only the gripper's own symmetry, since the task fixes the yaw.
        grasp: ``(4, 4)`` TCP grasp pose (default: :func:`grasp_pose`).
        align_origin: compensate the horizontal offset between the TCP and the object's origin
            (measured once the object is held), e.g. for an object grasped off-centre.
    """
    name = sim.scene.objects[index].name
    sym = grasp_symmetry(name) if grasp is None else GRIPPER_SYMMETRY
    grasp = grasp_pose(sim, index) if grasp is None else grasp
    above = grasp.copy()
    above[2, 3] += APPROACH_HEIGHT
    yield action(above, True, False, "approach", sym)
    yield action(grasp, False, True, "grasp", sym)
    lift = grasp.copy()
    lift[2, 3] += LIFT_HEIGHT
    yield action(lift, False, True, "lift", sym)
    # Height of the object's bottom below the TCP, measured now that it is held.
    obj = sim.object_pose(index)
    tcp = sim.robot.tcp_pose()
    bottom_below_tcp = tcp[2, 3] - (obj[2, 3] + object_geometry(name).lower[2])
    bottom_below_tcp = float(np.clip(bottom_below_tcp, 0.0, 0.2))
    # The commanded grasp yaw (not the measured one, which may sit across the canonical range's edge).
    place_sym = sym if place_yaw is None else GRIPPER_SYMMETRY
    yaw = finger_yaw(grasp) if place_yaw is None else place_yaw
    place = top_down_pose(np.zeros(3), yaw, place_sym)
    if align_origin:
        # Offset of the origin from the TCP in the TCP's yaw frame, turned to the placing yaw.
        offset = _rot2(finger_yaw(place) - finger_yaw(tcp)) @ (obj[:2, 3] - tcp[:2, 3])
        place_xy = np.asarray(place_xy, float) - offset
    place[:3, 3] = [place_xy[0], place_xy[1], surface_z + bottom_below_tcp + DROP_HEIGHT]
    move = place.copy()
    move[2, 3] = max(place[2, 3] + APPROACH_HEIGHT, lift[2, 3])
    yield action(move, False, False, "move", place_sym)     # move above the goal
    yield action(place, True, True, "place", place_sym)     # place and release
    retreat = place.copy()
    retreat[2, 3] += APPROACH_HEIGHT
    yield action(retreat, True, True, "retreat", place_sym)


def _rot2(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def resting_on(sim: Simulation, index: int, max_bottom: float) -> bool:
    """Whether object ``index`` is not held and its bottom is below ``max_bottom`` (m)."""
    if index in sim.held_objects():
        return False
    name = sim.scene.objects[index].name
    return bool(sim.object_pose(index)[2, 3] + object_geometry(name).lower[2] < max_bottom)
