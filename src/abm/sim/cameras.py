"""Render calibrated RGB-D-segmentation frames from the scene cameras.

This is the simulator boundary for cameras: MuJoCo cameras look along their -z axis with +y up; the
frames returned here follow abm's OpenCV convention (+z forward, +y down), with camera-to-world
extrinsics, metric depth along +z and pinhole intrinsics whose centred principal point is
``((W - 1) / 2, (H - 1) / 2)``.
"""

from __future__ import annotations

import functools
import importlib
import os
import platform
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from abm.errors import ExternalError
from abm.sim.frustum_culling import FrustumCulling, drawn_geoms, reflects
from abm.types import CameraFrame

if TYPE_CHECKING:
    import mujoco

_T = TypeVar("_T")
# MuJoCo camera axes -> OpenCV camera axes (flip y and z).
_MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


def intrinsics_matrix(fovy_deg: float, height: int, width: int) -> np.ndarray:
    """``(3, 3)`` pinhole matrix of a MuJoCo camera (square pixels, centred principal point)."""
    fy = 0.5 * height / np.tan(np.radians(fovy_deg) / 2)
    return np.array([[fy, 0.0, (width - 1) / 2], [0.0, fy, (height - 1) / 2], [0.0, 0.0, 1.0]])


def camera_extrinsics(model: mujoco.MjModel, data: mujoco.MjData, camera_id: int) -> np.ndarray:
    """``(4, 4)`` camera-to-world transform in OpenCV axes for MuJoCo camera ``camera_id``."""
    del model
    out = np.eye(4)
    out[:3, :3] = data.cam_xmat[camera_id].reshape(3, 3) @ _MJ_TO_CV
    out[:3, 3] = data.cam_xpos[camera_id]
    return out


def _use_backend(backend: str) -> bool:
    """Point MuJoCo's renderer at an offscreen GL backend (``"egl"`` or ``"osmesa"``)."""
    try:
        from mujoco.rendering.classic import gl_context

        gl_context.GLContext = importlib.import_module(f"mujoco.{backend}").GLContext
    except Exception:  # noqa: BLE001 - any import problem means "not available"
        return False
    os.environ["MUJOCO_GL"] = backend
    return True


def ensure_headless_gl() -> None:
    """Select EGL (else OSMesa) when no display exists and MuJoCo fell back to GLFW.

    MuJoCo reads ``MUJOCO_GL`` once when it is imported; ``abm.sim`` sets ``egl`` as default, but if
    ``mujoco`` was imported first the GLFW backend would be chosen and fail without a display.
    """
    if platform.system() != "Linux" or os.environ.get("DISPLAY"):
        return
    try:
        from mujoco.rendering.classic import gl_context
    except ImportError:  # pragma: no cover - other mujoco layouts
        return
    chosen = getattr(gl_context, "_MUJOCO_GL", "")
    if chosen in ("", "glfw", "enable", "enabled", "on", "true", "1"):
        _use_backend("egl") or _use_backend("osmesa")


def _offscreen(create: Callable[[], _T]) -> _T:
    """``create()`` a GL object headless (EGL, else OSMesa when EGL fails), or raise :class:`ExternalError`."""
    ensure_headless_gl()
    try:
        return create()
    except Exception as first:  # noqa: BLE001 - retry with the software backend
        if os.environ.get("MUJOCO_GL") == "egl" and _use_backend("osmesa"):
            try:
                return create()
            except Exception:  # noqa: BLE001
                pass
        raise ExternalError(
            f"MuJoCo cannot render offscreen ({first}). Use MUJOCO_GL=egl (Mesa EGL) or MUJOCO_GL=osmesa "
            "with `apt-get install -y libosmesa6`, set before mujoco is imported."
        ) from first


RASTERIZER_THREADS = "LP_NUM_THREADS"
"""Mesa llvmpipe's rasterizer threads (read when the process makes its first GL context; default: one per core)."""


def single_threaded_rasterizer() -> None:
    """Have Mesa's llvmpipe rasterize in the drawing thread (``LP_NUM_THREADS=0``) unless the user set the variable.

    For processes that draw with one thread per core in use, as evaluation workers do (one torch thread each): at
    128² the rasterizer threads' hand-offs cost more CPU than they share out (the pixels are the same). Mesa reads
    the variable when the process's first GL context is made; called later, it changes nothing in this process
    (processes it starts inherit it).
    """
    os.environ.setdefault(RASTERIZER_THREADS, "0")


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` of ``model`` at ``height`` x ``width`` pixels with its own GL context, headless (EGL,
    else OSMesa) when there is no display; the benchmark-CLIP data renderer uses it."""
    import mujoco

    return _offscreen(lambda: mujoco.Renderer(model, height, width))


_GL_CONTEXTS: dict[int, Any] = {}
"""Per thread: the offscreen GL context every :class:`CameraRig` of the thread draws in, kept for the process."""


def shared_gl_context() -> Any | None:
    """This thread's offscreen GL context (created on the first call, then reused: creating one costs ~0.3 CPU s
    with Mesa's llvmpipe), or ``None`` when MuJoCo renders without one (then :func:`make_renderer` is used)."""
    key = threading.get_ident()
    if key not in _GL_CONTEXTS:
        def create() -> Any:
            from mujoco.rendering.classic import gl_context

            cls = gl_context.GLContext
            return None if cls is None else cls(_GL_CONTEXT_SIZE, _GL_CONTEXT_SIZE)

        _GL_CONTEXTS[key] = _offscreen(create)
    return _GL_CONTEXTS[key]


_GL_CONTEXT_SIZE = 64  # px: the context's own surface, unused (MuJoCo draws into the model's offscreen buffer)


def scene_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` of ``model`` that draws in this thread's shared GL context (:func:`shared_gl_context`);
    only the model's own GL resources (meshes, textures: ``mujoco.MjrContext``) are made for it and freed by its
    ``close()``. The pixels are those of a ``mujoco.Renderer`` with its own context (same buffers, same calls)."""
    gl = shared_gl_context()
    if gl is None:
        return make_renderer(model, height, width)
    renderer: mujoco.Renderer = _offscreen(lambda: _shared_context_renderer()(model, height, width, gl))
    return renderer


@functools.cache
def _shared_context_renderer() -> type:
    """``mujoco.Renderer`` whose GL context is shared (see :func:`scene_renderer`): its ``__init__`` does what
    ``mujoco.Renderer.__init__`` does except creating a GL context, its ``close()`` leaves the context alone
    (a class made on first use: mujoco is imported only then)."""
    import mujoco

    class SharedContextRenderer(mujoco.Renderer):  # type: ignore[misc]
        def __init__(self, model: mujoco.MjModel, height: int, width: int, gl: Any) -> None:
            self._gl_context = None
            self._mjr_context = None
            buffer = model.vis.global_
            if width > buffer.offwidth or height > buffer.offheight:
                raise ValueError(f"image {width}x{height} exceeds the model's offscreen buffer "
                                 f"{buffer.offwidth}x{buffer.offheight}")
            self._width, self._height, self._model = width, height, model
            self._scene = mujoco.MjvScene(model=model, maxgeom=10000)
            self._scene_option = mujoco.MjvOption()
            self._rect = mujoco.MjrRect(0, 0, width, height)
            gl.make_current()
            self._mjr_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr_context)
            self._mjr_context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
            self._gl_context = gl
            self._depth_rendering = False
            self._segmentation_rendering = False

        def activate(self) -> None:
            """Make the shared context current and bind this renderer's offscreen buffer: other scenes' renderers
            alive in the thread bind theirs (mujoco.Renderer binds its buffer once, in a context of its own)."""
            if self._gl_context is not None and self._mjr_context is not None:
                self._gl_context.make_current()
                mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._mjr_context)

        def render(self, *, out: np.ndarray | None = None) -> np.ndarray:
            self.activate()
            image: np.ndarray = super().render(out=out)
            return image

        def close(self) -> None:
            if self._mjr_context is not None and self._gl_context is not None:
                try:
                    self._gl_context.make_current()
                except Exception:  # noqa: BLE001 - the process is ending and its GL context went first
                    pass
                else:
                    self._mjr_context.free()
            self._mjr_context = None
            self._gl_context = None  # the thread's context stays for the next scene

    return SharedContextRenderer


class CameraRig:
    """Renders the named cameras of a model into :class:`abm.types.CameraFrame` objects.

    Args:
        model: the compiled :class:`mujoco.MjModel`.
        camera_names: which model cameras to render.
        height, width: image size in pixels.
        geom_to_object: ``(ngeom,)`` int32 segmentation id of each geom (-1 = not an object).
        segmentation: draw each camera's segmentation (a second draw); without it a frame's ``segmentation`` is
            ``None`` and its depth comes from the colour draw's depth buffer (:meth:`_colour_and_depth`).

    Each camera draws only the mesh geoms whose bounding box reaches into its view (``culling``:
    :class:`abm.sim.frustum_culling.FrustumCulling`, ``None`` for models where that could change a pixel).
    """

    def __init__(self, model: mujoco.MjModel, camera_names: Sequence[str], height: int, width: int,
                 geom_to_object: np.ndarray, segmentation: bool = True) -> None:
        import mujoco

        self.model = model
        self.segmentation = bool(segmentation)
        self.height, self.width = int(height), int(width)
        self.camera_names = list(camera_names)
        self.camera_ids: list[int] = []
        for name in self.camera_names:
            cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid < 0:
                raise KeyError(f"camera {name!r} not in the model")
            self.camera_ids.append(cid)
        self.geom_to_object = np.asarray(geom_to_object, np.int32)
        self._renderer = scene_renderer(model, self.height, self.width)
        self.culling = FrustumCulling.for_model(model)  # None: every geom drawn by every camera
        self._geom_type = int(mujoco.mjtObj.mjOBJ_GEOM)
        self._zfar = float(model.vis.map.zfar * model.stat.extent)
        # depth and segmentation from one draw: None = not checked yet (the first frame checks it; once it passed,
        # the rigs made later in the process take it without the check's extra draws)
        self.one_pass: bool | None = True if _ONE_PASS_VERIFIED else None
        self._colour_depth: bool | None = None  # see _colour_depth_usable

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def render(self, data: mujoco.MjData) -> dict[str, CameraFrame]:
        """Render every camera at the current simulator state."""
        renderer = self._renderer
        frames: dict[str, CameraFrame] = {}
        activate = getattr(renderer, "activate", None)  # a renderer in the thread's shared GL context
        for name, cid in zip(self.camera_names, self.camera_ids, strict=True):
            if activate is not None:
                activate()
            renderer.update_scene(data, camera=cid)
            if self.culling is not None:
                self.culling.apply(renderer, data)
            seg: np.ndarray | None = None
            if self.segmentation or not self._colour_depth_usable():
                rgb = renderer.render().copy()
                depth, seg_raw = self._depth_and_segmentation()
                if self.segmentation:
                    seg = self._object_ids(seg_raw)
            else:
                rgb, depth = self._colour_and_depth()
            depth[~np.isfinite(depth) | (depth >= 0.99 * self._zfar)] = 0.0
            fovy = float(self.model.cam_fovy[cid])
            frames[name] = CameraFrame(
                rgb=rgb,
                depth=depth,
                intrinsics=intrinsics_matrix(fovy, self.height, self.width),
                extrinsics=camera_extrinsics(self.model, data, cid),
                segmentation=seg,
            )
        return frames

    def _object_ids(self, seg_raw: np.ndarray) -> np.ndarray:
        """``(H, W)`` int32 object id of each pixel (-1 = none) from the renderer's (object id, object type)."""
        ids, types = seg_raw[..., 0], seg_raw[..., 1]
        seg = np.full(ids.shape, -1, np.int32)
        is_geom = (types == self._geom_type) & (ids >= 0) & (ids < len(self.geom_to_object))
        seg[is_geom] = self.geom_to_object[ids[is_geom]]
        return seg

    def _colour_depth_usable(self) -> bool:
        """Whether the colour draw's depth buffer is the depth the segmentation draw gives (which the renderer's
        depth mode reads): for a model without transparent or reflecting surfaces, once this process compared
        the two on a frame and found them equal (the first such frame compares them)."""
        if self._colour_depth is None:
            opaque = _opaque(self.model)
            if not opaque:
                self._colour_depth = False
            elif _COLOUR_DEPTH_VERIFIED is None:
                colour_depth = self._colour_and_depth()[1]
                _set_colour_depth_verified(np.array_equal(colour_depth, self._depth_and_segmentation()[0],
                                                          equal_nan=True))
            self._colour_depth = bool(opaque and _COLOUR_DEPTH_VERIFIED)
        return self._colour_depth

    def _colour_and_depth(self) -> tuple[np.ndarray, np.ndarray]:
        """``(H, W, 3)`` uint8 colour and ``(H, W)`` float32 metric depth of one colour draw of the scene in the
        renderer (its depth buffer converted as the renderer's depth mode converts it)."""
        import mujoco

        renderer = self._renderer
        if renderer._gl_context:
            renderer._gl_context.make_current()
        colour = np.empty((self.height, self.width, 3), np.uint8)
        zbuffer = np.empty((self.height, self.width), np.float32)
        mujoco.mjr_render(renderer._rect, renderer._scene, renderer._mjr_context)
        mujoco.mjr_readPixels(colour, zbuffer, renderer._rect, renderer._mjr_context)
        depth = _metric_depth(zbuffer, renderer, self.model)
        if renderer._gl_context:  # EGL / OSMesa / GLFW images are upside down
            colour, depth = np.flipud(colour), np.flipud(depth)
        return np.ascontiguousarray(colour), np.ascontiguousarray(depth)

    def _depth_and_segmentation(self) -> tuple[np.ndarray, np.ndarray]:
        """``(H, W)`` float32 metric depth and ``(H, W, 2)`` int32 (object id, object type) of the scene in the
        renderer, as ``mujoco.Renderer``'s depth and segmentation modes return them.

        Both modes draw the same picture (flat id colours, for accurate far depth), so one draw can give both
        buffers: :func:`_one_pass_depth_and_segmentation` reads them together, a third fewer draws per camera.
        It mirrors the renderer's conversions, so the first frame checks it against the renderer's own two draws
        and keeps it only when both agree exactly (any other MuJoCo version falls back to two draws).
        """
        renderer = self._renderer
        if self.one_pass is not False:
            try:
                fast = _one_pass_depth_and_segmentation(renderer, self.model)
            except AttributeError:  # another MuJoCo layout: no such renderer internals
                fast = None
            if self.one_pass:
                assert fast is not None
                return fast
        renderer.enable_depth_rendering()
        depth = renderer.render().astype(np.float32)
        renderer.disable_depth_rendering()
        renderer.enable_segmentation_rendering()
        seg_raw = renderer.render()
        renderer.disable_segmentation_rendering()
        if self.one_pass is None:
            self.one_pass = fast is not None and np.array_equal(fast[0], depth, equal_nan=True) \
                and np.array_equal(fast[1], seg_raw)
            if self.one_pass:
                _verified_one_pass()
        return depth, seg_raw


_ONE_PASS_VERIFIED = False
"""Whether a rig of this process found the one-draw depth and segmentation equal to the renderer's own."""


def _verified_one_pass() -> None:
    global _ONE_PASS_VERIFIED
    _ONE_PASS_VERIFIED = True


def _opaque(model: mujoco.MjModel) -> bool:
    """Whether every geom drawn by default (the default ``MjvOption``'s geom groups) is opaque and no plane or box
    among them reflects (MuJoCo draws reflections on those only): the colour draw then writes the depth the
    segmentation draw writes."""
    drawn = drawn_geoms(model)
    matid = model.geom_matid[drawn]
    return bool(np.all(model.geom_rgba[drawn, 3] >= 1.0) and np.all(model.mat_rgba[matid[matid >= 0], 3] >= 1.0)
                and not reflects(model))


_COLOUR_DEPTH_VERIFIED: bool | None = None
"""Whether the colour draw's depth equalled the segmentation draw's on the first frame of this process that
compared them (``None``: none did yet)."""


def _set_colour_depth_verified(equal: bool) -> None:
    global _COLOUR_DEPTH_VERIFIED
    _COLOUR_DEPTH_VERIFIED = equal


def _metric_depth(zbuffer: np.ndarray, renderer: mujoco.Renderer, model: mujoco.MjModel) -> np.ndarray:
    """``(H, W)`` float32 metric depth of a reverse-Z depth buffer read from ``renderer``, converted as
    ``mujoco.Renderer``'s depth mode converts it (float32 projection coefficients, float64 arithmetic)."""
    extent = model.stat.extent
    znear, zfar = np.float32(model.vis.map.znear * extent), np.float32(model.vis.map.zfar * extent)
    z = zbuffer.astype(np.float64)
    if renderer._scene.camera[0].orthographic:
        z = zfar - z * (zfar - znear)
    else:  # reverse-Z perspective projection, undone as the renderer does (float32 coefficients)
        c = np.float32(-0.5) * (-(zfar + znear) / (zfar - znear)) - np.float32(0.5)
        d = np.float32(-0.5) * (-(np.float32(2) * zfar * znear) / (zfar - znear))
        z = d / (z + c)
    depth: np.ndarray = z.astype(np.float32)
    return depth


def _one_pass_depth_and_segmentation(renderer: mujoco.Renderer, model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Draw the scene in ``renderer`` once with segmentation colours and read its colour and depth buffers:
    ``mujoco.Renderer.render``'s depth mode (reverse-Z buffer to metric depth) and segmentation mode (colour to
    (object id, object type)) in one draw. Uses the renderer's internals (``_scene``, ``_rect``, ``_mjr_context``,
    ``_gl_context``) of MuJoCo's classic renderer; :meth:`CameraRig._depth_and_segmentation` checks the result."""
    import mujoco

    scene, rect, context = renderer._scene, renderer._rect, renderer._mjr_context
    height, width = renderer.height, renderer.width
    flags = scene.flags.copy()
    try:
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        if renderer._gl_context:
            renderer._gl_context.make_current()
        colour = np.empty((height, width, 3), np.uint8)
        zbuffer = np.empty((height, width), np.float32)
        mujoco.mjr_render(rect, scene, context)
        mujoco.mjr_readPixels(colour, zbuffer, rect, context)
    finally:
        np.copyto(scene.flags, flags)
    depth = _metric_depth(zbuffer, renderer, model)
    segid = colour.astype(np.uint32)
    segid = segid[..., 0] + segid[..., 1] * (2**8) + segid[..., 2] * (2**16)
    lookup = np.full((scene.ngeom + 1, 2), -1, np.int32)
    visible = [g for g in scene.geoms[:scene.ngeom] if g.segid != -1]
    lookup[np.array([g.segid + 1 for g in visible], np.int32), 0] = [g.objid for g in visible]
    lookup[np.array([g.segid + 1 for g in visible], np.int32), 1] = [g.objtype for g in visible]
    seg = lookup[segid]
    if renderer._gl_context:  # EGL / OSMesa / GLFW images are upside down
        depth, seg = np.flipud(depth), np.flipud(seg)
    return np.ascontiguousarray(depth), np.ascontiguousarray(seg)
