"""Procedural props of ABM-Bench built from primitives: jars and lids (with a bar handle), pegs and a square
ring, a stepped shelf and a potted plant.

Every builder adds geoms to the ``root`` body of a fresh :class:`mujoco.MjSpec`; the root body frame has
its origin at the centre of the footprint (jars, lids, pegs, rings: at the collision box centre) and
+z up. Dimensions are in metres. Geom groups are set by the caller (:mod:`abm.sim.catalog`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import mujoco

# --- dimensions (m) -------------------------------------------------------------------------------
JAR_RADIUS = 0.032
JAR_HALF_HEIGHT = 0.04
LID_RADIUS = 0.036
LID_HALF_THICKNESS = 0.005
# Bar handle on the lid (grasped across its width), along the lid's local x. 6.4 cm long: 4 pixels of the
# policy's 64² views over the 1 m workspace (1.56 cm per pixel), so its direction, which sets the grasp yaw,
# can be read from them; the 1.6 cm knob it replaced (lid version 1) covered one pixel.
LID_HANDLE_HALF = (0.032, 0.006, 0.012)
PEG_HALF = (0.008, 0.008, 0.035)           # square peg, 7 cm tall
RING_OUTER_HALF = 0.056                    # square ring: outer half width
RING_BAR_HALF_WIDTH = 0.008                # half width of each side bar
RING_HALF_HEIGHT = 0.01
SHELF_TIER_DEPTH = 0.13                    # along the shelf's local x
SHELF_HALF_WIDTH = 0.14                    # along local y
SHELF_BOTTOM_Z = 0.03                      # top surface of the bottom shelf above the table
SHELF_TOP_Z = 0.13                         # top surface of the top shelf
SHELF_BOARD = 0.006                        # half thickness of boards and panels
SHELF_BACK_TOP = 0.17                      # top of the back panel
POT_RADIUS = 0.045
POT_HALF_HEIGHT = 0.04
PLANT_HEIGHT = 0.17                        # top of the leaves above the table

WOOD = (0.62, 0.45, 0.28, 1.0)
TERRACOTTA = (0.72, 0.36, 0.22, 1.0)
LEAF = (0.18, 0.55, 0.2, 1.0)
LID_GREY = (0.6, 0.6, 0.62, 1.0)
RING_GREY = (0.35, 0.35, 0.38, 1.0)


def _geom(body: mujoco.MjsBody, kind: str, size: Sequence[float], pos: Sequence[float], rgba: Sequence[float],
          mass: float | None = None, collide: bool = True, quat: Sequence[float] | None = None) -> mujoco.MjsGeom:
    """Add a box / cylinder / ellipsoid geom with abm's contact parameters."""
    import mujoco

    types = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
             "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID}
    geom = body.add_geom(type=types[kind], size=list(size), pos=list(pos), rgba=list(rgba))
    if quat is not None:
        geom.quat = list(quat)
    geom.friction = [1.0, 0.01, 0.001]
    if mass is not None:
        geom.mass = mass
    if not collide:
        geom.contype = 0
        geom.conaffinity = 0
    return geom


def build_jar(root: mujoco.MjsBody, rgba: Sequence[float]) -> None:
    """A coloured jar (fixed) with a light rim band; origin at its centre."""
    _geom(root, "cylinder", (JAR_RADIUS, JAR_HALF_HEIGHT), (0, 0, 0), rgba)
    _geom(root, "cylinder", (JAR_RADIUS * 1.03, 0.006), (0, 0, JAR_HALF_HEIGHT - 0.008),
          (0.92, 0.92, 0.9, 1.0), collide=False)
    _geom(root, "cylinder", (JAR_RADIUS * 0.8, 0.0005), (0, 0, JAR_HALF_HEIGHT), (0.15, 0.15, 0.15, 1.0),
          collide=False)


def build_lid(root: mujoco.MjsBody, rgba: Sequence[float] = LID_GREY) -> None:
    """A jar lid: a disc with a dark bar handle across its top along local x (``LID_HANDLE_HALF``); origin at
    the centre of its bounding box."""
    total = LID_HALF_THICKNESS + LID_HANDLE_HALF[2]
    _geom(root, "cylinder", (LID_RADIUS, LID_HALF_THICKNESS), (0, 0, -total + LID_HALF_THICKNESS), rgba,
          mass=0.04)
    _geom(root, "box", LID_HANDLE_HALF, (0, 0, total - LID_HANDLE_HALF[2]), (0.3, 0.3, 0.32, 1.0), mass=0.015)


def build_peg(root: mujoco.MjsBody, rgba: Sequence[float]) -> None:
    """A coloured square peg (fixed); origin at its centre."""
    _geom(root, "box", PEG_HALF, (0, 0, 0), rgba)


def build_ring(root: mujoco.MjsBody, rgba: Sequence[float] = RING_GREY) -> None:
    """A square ring of four bars around a square hole; origin at its centre."""
    o, w, h = RING_OUTER_HALF, RING_BAR_HALF_WIDTH, RING_HALF_HEIGHT
    c = o - w
    for x, y, sx, sy in ((c, 0, w, o), (-c, 0, w, o), (0, c, o - 2 * w, w), (0, -c, o - 2 * w, w)):
        _geom(root, "box", (sx, sy, h), (x, y, 0), rgba, mass=0.02)


def build_shelf(root: mujoco.MjsBody, rgba: Sequence[float] = WOOD) -> None:
    """A stepped two-shelf unit (fixed), open from above so a top-down gripper reaches both shelves.

    Local frame: origin on the table at the footprint centre; the bottom shelf (surface at
    ``SHELF_BOTTOM_Z``) spans x in [-SHELF_TIER_DEPTH, 0] (the side facing the robot), the top shelf
    (surface at ``SHELF_TOP_Z``) spans x in [0, SHELF_TIER_DEPTH], both |y| < SHELF_HALF_WIDTH.
    """
    d, wy, t = SHELF_TIER_DEPTH, SHELF_HALF_WIDTH, SHELF_BOARD
    # Bottom shelf: a plinth.
    _geom(root, "box", (d / 2, wy, SHELF_BOTTOM_Z / 2), (-d / 2, 0, SHELF_BOTTOM_Z / 2), rgba)
    # Top shelf board, two side panels and a back panel carrying it.
    _geom(root, "box", (d / 2, wy, t), (d / 2, 0, SHELF_TOP_Z - t), rgba)
    side_h = (SHELF_TOP_Z - 2 * t) / 2
    for y in (-wy + t, wy - t):
        _geom(root, "box", (d / 2, t, side_h), (d / 2, y, side_h), rgba)
    back_h = SHELF_BACK_TOP / 2
    _geom(root, "box", (t, wy, back_h), (d - t, 0, back_h), rgba)
    # Darker front edges so the two shelves are told apart in images.
    edge = tuple(0.6 * c for c in rgba[:3]) + (1.0,)
    _geom(root, "box", (0.004, wy, 0.004), (-d + 0.004, 0, SHELF_BOTTOM_Z - 0.003), edge, collide=False)
    _geom(root, "box", (0.004, wy, 0.004), (0.004, 0, SHELF_TOP_Z - 0.003), edge, collide=False)


def build_plant(root: mujoco.MjsBody) -> None:
    """A potted plant (fixed): a terracotta pot (collides) with leaves (visual only) above it.

    Origin at the centre of the pot's bottom on the table.
    """
    _geom(root, "cylinder", (POT_RADIUS, POT_HALF_HEIGHT), (0, 0, POT_HALF_HEIGHT), TERRACOTTA)
    _geom(root, "cylinder", (POT_RADIUS * 0.9, 0.002), (0, 0, 2 * POT_HALF_HEIGHT), (0.3, 0.2, 0.12, 1.0),
          collide=False)
    top = 2 * POT_HALF_HEIGHT
    leaves = [((0, 0, top + 0.045), (0.03, 0.03, 0.045)),
              ((0.03, 0.0, top + 0.03), (0.035, 0.015, 0.03)),
              ((-0.03, 0.01, top + 0.035), (0.035, 0.016, 0.03)),
              ((0.0, 0.03, top + 0.03), (0.015, 0.035, 0.03)),
              ((0.005, -0.03, top + 0.04), (0.016, 0.035, 0.035)),
              ((0.0, 0.0, PLANT_HEIGHT - 0.02), (0.022, 0.022, 0.02))]
    for pos, size in leaves:
        _geom(root, "ellipsoid", size, pos, LEAF, collide=False)
