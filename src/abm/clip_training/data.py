"""Render an image-text set from the simulator for training the benchmark CLIP (``abm clip train``).

A *world* is one compiled MuJoCo model: a table with several materials, a floor, lights, one movable
camera, ``objects_per_world`` catalog objects (seen, unseen and compositional alike) and, with
probability ``robot_prob``, the Panda arm. Compiling costs most of the time, so every world is re-posed
``layouts_per_world`` times (a random subset of its objects on the table at random positions and yaws,
some stacked on a plate / pan / target pad, the rest moved out of sight; random table material and tint,
lights, robot posture) and every layout is seen from ``views_per_layout`` random viewpoints (around the
benchmark's cameras, or looking at a random point from a random direction, distance and field of view).

Each view yields:

* one **scene** sample: the ``image_size`` render with its per-pixel class map (dense loss only);
* up to ``crops_per_view`` **object crops**: a square around one object's segmentation (random margin and
  offset) from a ``crop_render`` px render, resized to ``image_size``, captioned with that object
  (contrastive loss and dense loss);
* sometimes a **background crop** (table, floor or robot, no object pixels), captioned accordingly.

Nothing comes from policy demonstrations. Samples are written to ``.npz`` shards (one shard = a fixed
list of world seeds, so rendering resumes shard by shard and gives the same data again):
``images (N, S, S, 3) uint8``, ``classes (N, S, S) uint8`` (class index per pixel, see
:func:`abm.clip_training.captions.class_names`), ``kind (N,) uint8`` (:data:`KINDS`), ``label (N,) int16``
(the caption's class, -1 for scenes) and ``caption (N,) str``.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from abm.clip_training.captions import BACKGROUND_CLASSES, FLOOR, ROBOT, TABLE, caption, class_names
from abm.errors import DataError, OutputError
from abm.files import atomic_path, write_text_atomic
from abm.progress import Progress
from abm.sim.cameras import ensure_headless_gl, make_renderer
from abm.sim.catalog import CATALOG, object_geometry, object_spec
from abm.sim.scene import HOME_QPOS, OBJECT_PREFIX, TABLE_CENTER_X, TABLE_HALF, robot_spec

log = logging.getLogger("abm")

KINDS: tuple[str, ...] = ("scene", "object", "background")
SCENE, OBJECT_CROP, BACKGROUND_CROP = 0, 1, 2
SUPPORTS: tuple[str, ...] = ("plate", "frypan", "target", "yellow plate", "wooden tray")
"""Objects other objects are sometimes placed on (as in place_food, take_off_pan, pick_block)."""
PLACE_X, PLACE_Y = (0.2, 0.8), (-0.45, 0.45)   # table region for object positions (m, world frame)
BENCH_TABLE_RGB = (0.72, 0.6, 0.46)            # abm.sim.scene's table colour
HIDDEN_X = 50.0                                # objects not in a layout are parked far away (m)
# Benchmark-like viewpoints: (eye, look-at) in metres, jittered per view (abm.sim.scene.CAMERAS).
BENCH_VIEWS: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
    ((1.35, 0.0, 0.75), (0.45, 0.0, 0.05)),
    ((0.05, 0.55, 0.8), (0.55, 0.0, 0.0)),
    ((0.05, -0.55, 0.8), (0.55, 0.0, 0.0)),
)


@dataclass(frozen=True)
class RenderConfig:
    """What one shard of the dataset contains.

    Attributes:
        image_size: side of every stored sample (px); the model's input size.
        crop_render: side of the render object crops are cut from (px), for sharper crops.
        worlds_per_shard: compiled worlds per shard file.
        objects_per_world: catalog objects compiled into a world.
        layouts_per_world: object arrangements per world.
        views_per_layout: viewpoints per arrangement.
        max_on_table: at most this many objects are on the table in one layout (at least 1).
        crops_per_view: object crops per view (largest-first among the visible objects, random order).
        background_crop_prob: chance of one background crop per view.
        robot_prob: chance that a world contains the Panda arm.
        min_crop_pixels: an object needs this many pixels in the ``crop_render`` image to be cropped.
        objects: object names to draw from (default: the whole catalog).
    """

    image_size: int = 128
    crop_render: int = 256
    worlds_per_shard: int = 2
    objects_per_world: int = 12
    layouts_per_world: int = 10
    views_per_layout: int = 4
    max_on_table: int = 6
    crops_per_view: int = 2
    background_crop_prob: float = 0.4
    robot_prob: float = 0.6
    min_crop_pixels: int = 120
    objects: tuple[str, ...] = field(default_factory=tuple)

    def object_names(self) -> tuple[str, ...]:
        if self.objects:
            return tuple(self.objects)

        return tuple(CATALOG)

    def to_json(self) -> dict[str, Any]:
        return asdict(self) | {"objects": list(self.object_names())}


@dataclass
class RenderSample:
    """One image-text sample: ``image (S, S, 3) uint8``, ``classes (S, S) uint8``, kind, label, caption."""

    image: np.ndarray
    classes: np.ndarray
    kind: int
    label: int
    caption: str


# --------------------------------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------------------------------
def look_at_quat(eye: np.ndarray, target: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """MuJoCo camera quaternion ``(w, x, y, z)`` looking from ``eye`` at ``target`` (m), rolled by ``roll`` rad.

    Near-vertical views use a horizontal up vector (the view direction's own azimuth), so the look-at
    never degenerates.
    """
    from scipy.spatial.transform import Rotation

    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    up = np.array([0.0, 0.0, 1.0])
    if abs(forward @ up) > 0.97:
        up = np.array([forward[0], forward[1], 0.0]) + np.array([1e-3, 0.0, 0.0])
        up /= np.linalg.norm(up)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    rot = np.stack([right, cam_up, -forward], axis=1) @ Rotation.from_euler("z", roll).as_matrix()
    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return np.array([w, x, y, z])


def square_crop_box(rows: np.ndarray, cols: np.ndarray, size: int, rng: np.random.Generator,
                    margin: tuple[float, float] = (1.3, 2.4), min_side: int = 24) -> tuple[int, int, int]:
    """A square ``(top, left, side)`` (px) around the pixels ``rows, cols`` of an ``size x size`` image.

    The side is the pixels' bounding-box side times a random margin, the centre is jittered by up to
    15 % of the side, and the square is shifted (and shrunk if needed) to lie inside the image; it always
    contains the bounding box's centre.
    """
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    side = int(round(max(r1 - r0, c1 - c0) * rng.uniform(*margin)))
    side = int(np.clip(side, min_side, size))
    cr = (r0 + r1) / 2 + rng.uniform(-0.15, 0.15) * side
    cc = (c0 + c1) / 2 + rng.uniform(-0.15, 0.15) * side
    top = int(np.clip(round(cr - side / 2), 0, size - side))
    left = int(np.clip(round(cc - side / 2), 0, size - side))
    return top, left, side


def resize_pair(image: np.ndarray, classes: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Resize an RGB image (area / bicubic) and its class map (nearest) to ``size x size``."""
    from PIL import Image

    if image.shape[0] == size and image.shape[1] == size:
        return image, classes
    resample = Image.Resampling.BOX if image.shape[0] > size else Image.Resampling.BICUBIC
    img = np.asarray(Image.fromarray(image).resize((size, size), resample))
    cls = np.asarray(Image.fromarray(classes).resize((size, size), Image.Resampling.NEAREST))
    return img, cls


# --------------------------------------------------------------------------------------------------
# The world
# --------------------------------------------------------------------------------------------------
class World:
    """One compiled scene that is re-posed, re-lit and re-viewed many times.

    Args:
        names: catalog objects compiled into the world.
        classes: the class list (object names, then the background classes) defining class indices.
        robot: include the Panda arm.
        rng: drives the materials made at compile time.
        sizes: square render sizes needed (px).
    """

    def __init__(self, names: Sequence[str], classes: Sequence[str], robot: bool, rng: np.random.Generator,
                 sizes: Sequence[int]) -> None:
        import mujoco

        self.names = list(names)
        self.index = {c: i for i, c in enumerate(classes)}
        spec = robot_spec(with_actuators=False) if robot else mujoco.MjSpec()
        spec.visual.quality.offsamples = 0
        spec.visual.map.znear = 0.01
        spec.visual.map.zfar = 10.0
        spec.stat.extent = 2.0
        spec.visual.global_.offwidth = max(sizes)
        spec.visual.global_.offheight = max(sizes)
        world = spec.worldbody
        world.add_light(name="key", pos=[0.6, 0.0, 2.0], dir=[0, 0, -1], diffuse=[0.5, 0.5, 0.5], castshadow=False)
        self.materials = self._add_materials(spec, rng)
        floor = world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1],
                               pos=[0, 0, -0.75], material="floor_mat")
        floor.group = 0
        table = world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(TABLE_HALF),
                               pos=[TABLE_CENTER_X, 0, -TABLE_HALF[2]], material=self.materials[0])
        table.group = 0
        world.add_camera(name="cam", pos=[1.0, 0, 1.0], quat=[1, 0, 0, 0], fovy=45.0)
        for i, name in enumerate(self.names):
            child = object_spec(name)
            frame = world.add_frame(pos=[HIDDEN_X + i, 0.0, 0.5])
            body = frame.attach_body(child.body("root"), OBJECT_PREFIX.format(i), "")
            body.add_freejoint(name=f"{OBJECT_PREFIX.format(i)}free")
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._mujoco = mujoco
        self.rest_z = [-object_geometry(n).lower[2] + 1e-4 for n in self.names]
        self.top_z = [object_geometry(n).upper[2] for n in self.names]
        self.radius = [object_geometry(n).footprint_radius for n in self.names]
        self.qpos_adr = [m.jnt_qposadr[m.joint(f"{OBJECT_PREFIX.format(i)}free").id] for i in range(len(self.names))]
        # geom -> class index (objects by their root body, the table, the robot, the rest is "floor")
        geom_class = np.full(m.ngeom, self.index[FLOOR], np.int32)
        geom_class[m.geom("table").id] = self.index[TABLE]
        root_of_geom = m.body_rootid[m.geom_bodyid]
        for i, name in enumerate(self.names):
            geom_class[root_of_geom == m.body(f"{OBJECT_PREFIX.format(i)}root").id] = self.index[name]
        if robot:
            geom_class[root_of_geom == m.body("panda_link0").id] = self.index[ROBOT]
            self.arm_adr = [m.jnt_qposadr[m.joint(f"panda_joint{k}").id] for k in range(1, 8)]
            self.finger_adr = [m.jnt_qposadr[j] for j in range(m.njnt) if "finger_joint" in m.joint(j).name]
        else:
            self.arm_adr, self.finger_adr = [], []
        self.geom_class = geom_class
        self.table_geom = m.geom("table").id
        self.material_ids = [m.material(n).id for n in self.materials]
        self.camera = m.camera("cam").id
        self._renderers: dict[int, Any] = {}
        self.sizes = tuple(sizes)

    @staticmethod
    def _add_materials(spec: Any, rng: np.random.Generator) -> list[str]:
        """Table materials: plain, checker, gradient, random dots and a noise texture; a floor material."""
        import mujoco

        def colour() -> list[float]:
            return [float(v) for v in rng.uniform(0.15, 0.95, 3)]

        builtin = mujoco.mjtBuiltin
        spec.add_texture(name="floor_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=builtin.mjBUILTIN_CHECKER,
                         rgb1=colour(), rgb2=colour(), width=128, height=128)
        spec.add_material(name="floor_mat", textures=["", "floor_tex"], texrepeat=[8, 8])
        names = ["table_plain"]
        spec.add_material(name="table_plain")
        for kind, b in (("checker", builtin.mjBUILTIN_CHECKER), ("gradient", builtin.mjBUILTIN_GRADIENT)):
            spec.add_texture(name=f"table_{kind}_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=b,
                             rgb1=colour(), rgb2=colour(), width=128, height=128)
            spec.add_material(name=f"table_{kind}", textures=["", f"table_{kind}_tex"],
                              texrepeat=[float(rng.integers(2, 12))] * 2)
            names.append(f"table_{kind}")
        noise = (rng.random((64, 64, 1)) * 0.35 + 0.65) * np.array(colour())  # grainy, wood-like
        noise = np.repeat(noise, 4, axis=1) if rng.random() < 0.5 else noise
        noise = np.ascontiguousarray((noise[:64, :64] * 255).astype(np.uint8))
        tex = spec.add_texture(name="table_noise_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, width=64, height=64,
                               nchannel=3)
        tex.data = noise.tobytes()
        spec.add_material(name="table_noise", textures=["", "table_noise_tex"], texrepeat=[2, 2])
        names.append("table_noise")
        return names

    def renderer(self, size: int) -> Any:
        if size not in self._renderers:
            self._renderers[size] = make_renderer(self.model, size, size)
        return self._renderers[size]

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()

    # ---- layouts ---------------------------------------------------------------------------------
    def layout(self, rng: np.random.Generator, max_on_table: int) -> list[int]:
        """Random arrangement: returns the indices (into :attr:`names`) of the objects on the table."""
        m, d = self.model, self.data
        qpos = d.qpos
        for i, adr in enumerate(self.qpos_adr):  # park everything
            qpos[adr:adr + 7] = [HIDDEN_X + 2 * i, 0.0, 0.5, 1, 0, 0, 0]
        count = int(rng.integers(1, min(max_on_table, len(self.names)) + 1))
        order = rng.permutation(len(self.names))[:count]
        placed: list[tuple[float, float, float]] = []   # (x, y, radius) of objects standing on the table
        supports: list[tuple[int, float, float]] = []   # (index, x, y) of supports on the table
        shown = []
        for i in order:
            name, yaw = self.names[i], rng.uniform(-np.pi, np.pi)
            if supports and name not in SUPPORTS and self.radius[i] < 0.08 and rng.random() < 0.3:
                s, x, y = supports[int(rng.integers(len(supports)))]
                z = self.rest_z[s] + self.top_z[s] + self.rest_z[i] + 0.002
                x, y = x + rng.uniform(-0.02, 0.02), y + rng.uniform(-0.02, 0.02)
            else:
                for _ in range(40):
                    x, y = rng.uniform(*PLACE_X), rng.uniform(*PLACE_Y)
                    if all(np.hypot(x - px, y - py) > self.radius[i] + pr + 0.01 for px, py, pr in placed):
                        break
                else:
                    continue
                z = self.rest_z[i]
                placed.append((x, y, self.radius[i]))
                if name in SUPPORTS:
                    supports.append((int(i), x, y))
            qpos[self.qpos_adr[i]:self.qpos_adr[i] + 7] = [x, y, z, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
            shown.append(int(i))
        if self.arm_adr:
            home = np.asarray(HOME_QPOS)
            qpos[self.arm_adr] = home + rng.normal(0, 0.25, 7) * np.array([1.5, 1, 1, 1, 1, 1, 1.5])
            qpos[self.finger_adr] = rng.uniform(0.0, 0.04)
        # appearance: table material and tint, floor tint, lights
        m.geom_matid[self.table_geom] = self.material_ids[int(rng.integers(len(self.material_ids)))]
        if rng.random() < 0.25:  # the benchmark's plain wooden table, slightly varied
            m.geom_matid[self.table_geom] = self.material_ids[0]
            tint = np.clip(np.array(BENCH_TABLE_RGB) + rng.normal(0, 0.04, 3), 0, 1)
        else:
            tint = rng.uniform(0.55, 1.0, 3) if rng.random() < 0.7 else rng.uniform(0.2, 1.0, 3)
        m.mat_rgba[m.geom_matid[self.table_geom], :3] = tint
        m.mat_rgba[m.material("floor_mat").id, :3] = rng.uniform(0.3, 1.0, 3)
        m.vis.headlight.ambient[:] = rng.uniform(0.15, 0.55)
        m.vis.headlight.diffuse[:] = rng.uniform(0.2, 0.7)
        m.light_pos[0] = [rng.uniform(-0.2, 1.2), rng.uniform(-0.8, 0.8), rng.uniform(0.8, 2.5)]
        m.light_dir[0] = (np.array([0.5, 0.0, 0.0]) - m.light_pos[0]) / np.linalg.norm(
            np.array([0.5, 0.0, 0.0]) - m.light_pos[0])
        m.light_diffuse[0] = rng.uniform(0.2, 0.8) * rng.uniform(0.85, 1.0, 3)
        self._mujoco.mj_kinematics(m, d)
        return shown

    def view(self, rng: np.random.Generator, shown: Sequence[int]) -> None:
        """Place the camera: near a benchmark camera (35 %) or looking at a random point (65 %)."""
        m, d = self.model, self.data
        if rng.random() < 0.35:
            eye, target = (np.array(v, float) for v in BENCH_VIEWS[int(rng.integers(len(BENCH_VIEWS)))])
            eye += rng.normal(0, 0.08, 3)
            target += rng.normal(0, 0.06, 3)
            fovy, roll = rng.uniform(38, 54), rng.normal(0, 0.05)
        else:
            if shown and rng.random() < 0.7:
                i = shown[int(rng.integers(len(shown)))]
                target = d.qpos[self.qpos_adr[i]:self.qpos_adr[i] + 3].copy() + rng.normal(0, 0.05, 3)
            else:
                target = np.array([rng.uniform(*PLACE_X), rng.uniform(*PLACE_Y), 0.0])
            azimuth, elevation = rng.uniform(-np.pi, np.pi), np.radians(rng.uniform(20, 89))
            dist = rng.uniform(0.3, 1.5)
            eye = target + dist * np.array([np.cos(elevation) * np.cos(azimuth),
                                            np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
            fovy = rng.uniform(30, 70)
            roll = rng.normal(0, 0.15) if rng.random() < 0.7 else rng.uniform(-np.pi, np.pi)
        m.cam_pos[self.camera] = eye
        m.cam_quat[self.camera] = look_at_quat(eye, target, roll)
        m.cam_fovy[self.camera] = fovy
        self._mujoco.mj_kinematics(m, d)
        self._mujoco.mj_camlight(m, d)

    def render(self, size: int) -> tuple[np.ndarray, np.ndarray]:
        """``(rgb (S, S, 3) uint8, classes (S, S) uint8)`` from the camera at its current pose."""
        r = self.renderer(size)
        r.update_scene(self.data, camera=self.camera)
        rgb = r.render().copy()
        r.enable_segmentation_rendering()
        seg = r.render()
        r.disable_segmentation_rendering()
        ids, types = seg[..., 0], seg[..., 1]
        classes = np.full(ids.shape, self.index[FLOOR], np.uint8)
        is_geom = (types == int(self._mujoco.mjtObj.mjOBJ_GEOM)) & (ids >= 0) & (ids < len(self.geom_class))
        classes[is_geom] = self.geom_class[ids[is_geom]]
        return rgb, classes


# --------------------------------------------------------------------------------------------------
# Samples
# --------------------------------------------------------------------------------------------------
def object_crops(rgb: np.ndarray, classes: np.ndarray, objects: Sequence[int], config: RenderConfig,
                 names: Sequence[str], rng: np.random.Generator) -> Iterator[RenderSample]:
    """Crops around the visible objects (class indices ``objects``) of a ``crop_render`` image."""
    counts = {c: int((classes == c).sum()) for c in objects}
    visible = [c for c in objects if counts[c] >= config.min_crop_pixels]
    for c in [visible[i] for i in rng.permutation(len(visible))][:config.crops_per_view]:
        rows, cols = np.nonzero(classes == c)
        top, left, side = square_crop_box(rows, cols, classes.shape[0], rng)
        img, cls = resize_pair(rgb[top:top + side, left:left + side], classes[top:top + side, left:left + side],
                               config.image_size)
        if (cls == c).mean() < 0.04:  # the object must be clearly in the crop
            continue
        yield RenderSample(img, cls, OBJECT_CROP, int(c), caption(names[c], rng))


def background_crop(rgb: np.ndarray, classes: np.ndarray, config: RenderConfig, names: Sequence[str],
                    background: Sequence[int], rng: np.random.Generator) -> RenderSample | None:
    """A crop showing (almost) only one background class, or None when none was found in a few tries."""
    size = classes.shape[0]
    for _ in range(6):
        side = int(rng.integers(size // 6, size // 2))
        top, left = (int(v) for v in rng.integers(0, size - side, 2))
        cls = classes[top:top + side, left:left + side]
        values, counts = np.unique(cls, return_counts=True)
        best = values[np.argmax(counts)]
        if best in background and counts.max() >= 0.8 * cls.size and np.isin(cls, background).mean() > 0.98:
            img, cls = resize_pair(rgb[top:top + side, left:left + side], cls, config.image_size)
            return RenderSample(img, cls, BACKGROUND_CROP, int(best), caption(names[int(best)], rng))
    return None


def render_world(seed: Sequence[int], config: RenderConfig, classes: Sequence[str]) -> list[RenderSample]:
    """All samples of one world (see the module docstring); deterministic for a given seed."""
    rng = np.random.default_rng(list(seed))
    names = list(config.object_names())
    chosen = [names[i] for i in rng.choice(len(names), size=min(config.objects_per_world, len(names)),
                                           replace=False)]
    world = World(chosen, classes, robot=bool(rng.random() < config.robot_prob), rng=rng,
                  sizes=(config.image_size, config.crop_render))
    index = {c: i for i, c in enumerate(classes)}
    background = [index[b] for b in BACKGROUND_CLASSES]
    samples: list[RenderSample] = []
    try:
        for _ in range(config.layouts_per_world):
            shown = world.layout(rng, config.max_on_table)
            objects = [index[world.names[i]] for i in shown]
            for _ in range(config.views_per_layout):
                world.view(rng, shown)
                rgb, cls = world.render(config.image_size)
                samples.append(RenderSample(rgb, cls, SCENE, -1, ""))
                big_rgb, big_cls = world.render(config.crop_render)
                samples.extend(object_crops(big_rgb, big_cls, objects, config, classes, rng))
                if rng.random() < config.background_crop_prob:
                    sample = background_crop(big_rgb, big_cls, config, classes, background, rng)
                    if sample is not None:
                        samples.append(sample)
    finally:
        world.close()
    return samples


def stack_samples(samples: Sequence[RenderSample]) -> dict[str, np.ndarray]:
    """Samples -> the arrays of one shard (see the module docstring)."""
    return {
        "images": np.stack([s.image for s in samples]).astype(np.uint8),
        "classes": np.stack([s.classes for s in samples]).astype(np.uint8),
        "kind": np.array([s.kind for s in samples], np.uint8),
        "label": np.array([s.label for s in samples], np.int16),
        "caption": np.array([s.caption for s in samples], dtype=np.str_),
    }


def render_shard(shard: int, base_seed: int, config: RenderConfig, classes: Sequence[str]) -> dict[str, np.ndarray]:
    """The arrays of shard ``shard``: worlds with seeds ``(base_seed, shard, w)``, ``w < worlds_per_shard``."""
    samples: list[RenderSample] = []
    for w in range(config.worlds_per_shard):
        samples += render_world((base_seed, shard, w), config, classes)
    return stack_samples(samples)


# --------------------------------------------------------------------------------------------------
# Dataset folder
# --------------------------------------------------------------------------------------------------
META = "dataset.json"


def shard_path(folder: Path, shard: int) -> Path:
    return folder / f"shard_{shard:05d}.npz"


def _write_shard(folder: Path, shard: int, base_seed: int, config: RenderConfig, classes: Sequence[str]) -> int:
    """Render one shard and write it atomically; returns its sample count."""
    ensure_headless_gl()
    arrays = render_shard(shard, base_seed, config, classes)
    path = shard_path(folder, shard)
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]  # numpy's stub: **arrays vs allow_pickle
    return int(arrays["kind"].shape[0])


def _shard_worker(args: tuple[str, int, int, dict[str, Any], list[str]]) -> tuple[int, int]:
    folder, shard, base_seed, cfg, classes = args
    import torch

    torch.set_num_threads(1)
    cfg = dict(cfg, objects=tuple(cfg["objects"]))
    return shard, _write_shard(Path(folder), shard, base_seed, RenderConfig(**cfg), classes)


def build_dataset(folder: str | Path, shards: int, config: RenderConfig | None = None, base_seed: int = 0,
                  workers: int = 1, progress: bool = True) -> Path:
    """Render ``shards`` shards into ``folder`` (resumable: existing shards are kept).

    ``folder/dataset.json`` records the configuration, class list and seed; a folder rendered with other
    settings is refused rather than mixed. Returns ``folder``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    config = config or RenderConfig()
    meta_path = folder / META
    classes = list(class_names(config.object_names()))
    meta = {"config": config.to_json(), "classes": classes, "base_seed": int(base_seed)}
    if meta_path.is_file():
        old = json.loads(meta_path.read_text(encoding="utf-8"))
        if {k: old.get(k) for k in meta} != meta:
            raise OutputError(f"{folder} holds a dataset rendered with other settings ({meta_path}); "
                              "use another folder or delete it")
    else:
        write_text_atomic(meta_path, json.dumps(meta, indent=2) + "\n")
    todo = [s for s in range(shards) if not shard_path(folder, s).is_file()]
    if not todo:
        return folder
    start = time.perf_counter()
    bar = Progress(shards, f"render {folder.name}", "shards", initial=shards - len(todo), bar=progress)
    jobs = [(str(folder), s, int(base_seed), config.to_json(), classes) for s in todo]
    if workers <= 1:
        for job in jobs:
            _shard_worker(job)
            bar.update(1)
    else:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(workers) as pool:
            for _ in pool.imap_unordered(_shard_worker, jobs):
                bar.update(1)
    bar.close()
    log.info("rendered %d shards into %s in %.0f s", len(todo), folder, time.perf_counter() - start)
    return folder


@dataclass
class ClipDataset:
    """All shards of a dataset folder in memory.

    Attributes:
        images: ``(N, S, S, 3)`` uint8.
        classes: ``(N, S, S)`` uint8 class index per pixel.
        kind: ``(N,)`` uint8 (:data:`KINDS`).
        label: ``(N,)`` int16 caption class (-1 for scenes).
        caption: ``(N,)`` captions ("" for scenes).
        class_names: the class list the indices refer to.
    """

    images: np.ndarray
    classes: np.ndarray
    kind: np.ndarray
    label: np.ndarray
    caption: np.ndarray
    class_names: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.kind.shape[0])


def load_dataset(folder: str | Path, shards: int | None = None) -> ClipDataset:
    """Load the first ``shards`` shards (default all) of a dataset folder."""
    folder = Path(folder)
    meta = json.loads((folder / META).read_text(encoding="utf-8"))
    paths = sorted(folder.glob("shard_*[0-9].npz"))[:shards]
    if not paths:
        raise DataError(f"no shards in {folder}")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("images", "classes", "kind", "label", "caption")}
    for path in paths:
        with np.load(path, allow_pickle=False) as z:
            for k in parts:
                parts[k].append(z[k])
    return ClipDataset(**{k: np.concatenate(v) for k, v in parts.items()}, class_names=tuple(meta["classes"]))
