"""Per-camera frustum culling of a MuJoCo scene's mesh geoms: what no pixel of a camera can show is not drawn.

Mesa's llvmpipe (the CPU renderer of a headless machine) spends most of a 128² draw on the scene's mesh triangles
(~185k in a place_food scene: ``benchmarks/frustum_culling.py``), also on those outside the camera's view, which it
transforms and clips before dropping them. A mesh geom whose bounding box lies entirely outside a camera's view
frustum draws no pixel of that camera, so :meth:`FrustumCulling.apply` takes it out of the camera's
``mujoco.MjvScene`` (after ``update_scene``, before the draws): its display list is not called. The frustum is the
one ``mjr_render`` projects with (:func:`_frustum_planes`: the eye cameras' average, as wide as the viewport's
aspect asks or, for a camera with a ``sensorsize``, as its ``frustum_width`` says). The colour, depth and
segmentation of every pixel stay the same, as long as nothing outside the view is seen through something inside
it: :meth:`FrustumCulling.for_model` refuses models with reflecting geoms (MuJoCo draws the scene mirrored in
them) or shadow-casting lights (a shadow map draws the scene from the light).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import mujoco

MARGIN_M = 1e-3
"""Added to the reach of every box (metres), with :data:`MARGIN_SCALE`: a geom at the frustum's edge is kept."""
MARGIN_SCALE = 1.01


def drawn_geoms(model: mujoco.MjModel) -> np.ndarray:
    """``(ngeom,)`` bool: the geoms of the geom groups a default ``mujoco.MjvOption`` draws."""
    import mujoco

    groups = [g for g, shown in enumerate(mujoco.MjvOption().geomgroup) if shown]
    drawn: np.ndarray = np.isin(model.geom_group, groups)
    return drawn


def reflects(model: mujoco.MjModel) -> bool:
    """Whether a drawn plane or box has a reflecting material (MuJoCo draws reflections on those only)."""
    import mujoco

    flat = drawn_geoms(model) & np.isin(model.geom_type, [mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_BOX]) \
        & (model.geom_matid >= 0)
    return bool(np.any(model.mat_reflectance[model.geom_matid[flat]] > 0.0))


def casts_shadows(model: mujoco.MjModel) -> bool:
    """Whether the renderer draws shadow maps for ``model``: a light casts shadows and the shadow map has a size."""
    return bool(model.vis.quality.shadowsize > 0 and np.any(model.light_castshadow))


def mesh_slots(scene: mujoco.MjvScene) -> list[int]:
    """Indices into ``scene.geoms`` of the model's mesh geoms that draw a mesh (``dataid``: a display list)."""
    import mujoco

    mesh, geom = int(mujoco.mjtGeom.mjGEOM_MESH), int(mujoco.mjtObj.mjOBJ_GEOM)
    return [i for i, g in enumerate(scene.geoms[:scene.ngeom]) if g.type == mesh and g.objtype == geom
            and g.dataid >= 0]


class FrustumCulling:
    """Takes the mesh geoms outside a camera's view frustum out of a scene before it is drawn.

    Args:
        model: the compiled model; its meshes' bounding boxes (in each mesh's frame, which is its geom's frame)
            are computed from their vertices once.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        centres, halves = np.zeros((model.nmesh, 3)), np.zeros((model.nmesh, 3))
        for mesh in range(model.nmesh):
            start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
            vertices = model.mesh_vert[start:start + count].astype(np.float64)
            low, high = vertices.min(axis=0), vertices.max(axis=0)
            centres[mesh], halves[mesh] = (low + high) / 2, (high - low) / 2
        self._box_centre, self._box_half = centres, halves
        self.triangles_culled = 0
        """Mesh triangles left out of the cameras' scenes so far (each :meth:`apply`: one camera's observation)."""

    @classmethod
    def for_model(cls, model: mujoco.MjModel) -> FrustumCulling | None:
        """A culling for ``model``, or ``None`` when something outside a camera's view can change its pixels
        (reflections, shadows)."""
        return None if reflects(model) or casts_shadows(model) else cls(model)

    def apply(self, renderer: Any, data: mujoco.MjData) -> int:
        """Take the mesh geoms outside the view of ``renderer``'s scene camera (set by its ``update_scene``) out of
        its scene (their mesh id becomes -1: MuJoCo draws no mesh for them). Returns the triangles left out."""
        scene = renderer._scene
        if scene.enabletransform or scene.stereo:
            return 0
        geoms = scene.geoms[:scene.ngeom]
        slots = mesh_slots(scene)
        if not slots:
            return 0
        geom_ids = np.array([geoms[i].objid for i in slots])
        meshes = self.model.geom_dataid[geom_ids]  # the scene's dataid is MuJoCo's display list index, not this
        outside = self._outside(renderer, scene, data.geom_xpos[geom_ids],
                                data.geom_xmat[geom_ids].reshape(-1, 3, 3), meshes)
        for k in np.flatnonzero(outside):
            geoms[slots[k]].dataid = -1
        culled = int(self.model.mesh_facenum[meshes[outside]].sum())
        self.triangles_culled += culled
        return culled

    def _outside(self, renderer: Any, scene: Any, positions: np.ndarray, rotations: np.ndarray,
                 meshes: np.ndarray) -> np.ndarray:
        """``(n,)`` bool: whether each mesh's box (geom frame ``positions`` ``(n, 3)``, ``rotations`` ``(n, 3, 3)``)
        lies entirely on the outer side of one plane of the frustum ``mujoco.mjr_render`` draws with."""
        normals, offsets = _frustum_planes(scene, renderer.width / renderer.height)
        centres = positions + np.einsum("nij,nj->ni", rotations, self._box_centre[meshes])
        distance = centres @ normals.T + offsets  # (n, 6): > 0 on the outer side of each plane
        along = np.abs(np.einsum("pk,nkj->npj", normals, rotations))  # |plane normal . box axis j|
        reach = np.einsum("npj,nj->np", along, self._box_half[meshes])  # (n, 6): the box's half-extent
        outside: np.ndarray = np.any(distance > MARGIN_SCALE * reach + MARGIN_M, axis=1)
        return outside


def _frustum_planes(scene: Any, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """``(6, 3)`` unit outward normals and ``(6,)`` offsets (world frame) of the view frustum ``mjr_render`` sets
    for ``scene``'s camera in a viewport of width / height ``aspect``, as MuJoCo's ``setView`` computes it: the
    average of the scene's two eye cameras (``mujoco.mjv_averageCamera``), whose half-width at the near plane is
    its ``frustum_width`` when that is non-zero (a camera with a ``sensorsize``: its intrinsics fix the width,
    whatever the viewport), else the frustum's height times half the viewport's ``aspect``. A point ``p`` is
    outside when ``normals @ p + offsets > 0`` for some plane."""
    import mujoco

    cam = mujoco.mjv_averageCamera(scene.camera[0], scene.camera[1])
    position = np.asarray(cam.pos, np.float64)
    forward = np.asarray(cam.forward, np.float64)
    forward /= np.linalg.norm(forward)
    up = np.asarray(cam.up, np.float64)
    up -= forward * (up @ forward)
    up /= np.linalg.norm(up)
    right = np.cross(forward, up)
    near, far = float(cam.frustum_near), float(cam.frustum_far)
    top, bottom = float(cam.frustum_top), float(cam.frustum_bottom)
    half_width = float(cam.frustum_width) or 0.5 * aspect * (top - bottom)
    left_edge, right_edge = cam.frustum_center - half_width, cam.frustum_center + half_width
    if cam.orthographic:  # sides parallel to the view axis
        local = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, -1], [0, 0, 1]], np.float64)
        local_offsets = np.array([-right_edge, left_edge, -top, bottom, near, -far])
    else:  # sides through the eye: x * near - right_edge * z > 0 is right of the frustum, etc.
        local = np.array([[near, 0, -right_edge], [-near, 0, left_edge], [0, near, -top], [0, -near, bottom],
                          [0, 0, -1], [0, 0, 1]], np.float64)
        local_offsets = np.array([0, 0, 0, 0, near, -far], np.float64)
    scale = np.linalg.norm(local, axis=1)
    local, local_offsets = local / scale[:, None], local_offsets / scale
    normals = local @ np.stack([right, up, forward])  # camera axes (rows) -> world
    return normals, local_offsets - normals @ position
