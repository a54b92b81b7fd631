"""3-D object proposals: split the fused cloud into object candidates, to be scored by CLIP.

The mask of the method lives in 3-D, where objects are cheap to separate geometrically. A
:class:`ClipGrounder` with ``mode="proposals"`` scores the candidates of :func:`object_proposals` against
the target text and marks the best one's points, so the mask is a whole object instead of the patches that
passed a threshold (:mod:`abm.grounding.grounders`).

1. **Table.** The table top is the most common point height (the mode of a 5 mm histogram of ``z``; or
   :attr:`ProposalConfig.table_height`). Points up to ``table_margin`` above it are table.
2. **Clusters.** The other points are put in ``voxel``-sized cells; 26-connected occupied cells form a
   cluster (``scipy.ndimage.label``). Clusters with fewer than ``min_points`` points are dropped.
3. **Splits** (``split=True``; off by default). An object standing in or on another one (food on a plate,
   the steak in the pan, a bottle in the rack, items on the shelf, a peg on its base) touches it and joins
   its cluster.
   Inside a cluster, neighbouring cells of one surface colour (:func:`same_colour`: the same chromaticity
   within ``color_tol``, so shading does not split an object) are joined again: each such colour part is a
   candidate, and so is the cluster
   *without* each large colour part (the support removed: plate + cookies - plate = cookies, even when the
   cookies' print splits them into several colours). The whole cluster stays a candidate too, so a
   multi-coloured object that stands alone is not lost. Candidates may overlap; scoring picks one.
   **Hand.** With the gripper's pose and opening (``hand_filter``, on by default), the Panda hand's points
   (:func:`hand_points`: the palm and wrist behind the finger bases, and the two fingers at the opening) are
   left out before clustering: otherwise an object held between the fingers joins the hand and arm into one
   cluster, and its mask covers the robot (measured on place_wine: ~9000 points instead of the bottle's
   ~1300 once it is lifted).
4. **Base points.** The chosen candidate takes back the table-height points within one voxel of it that
   have its colour (the bottom of a flat object lies inside the table margin).

Nothing here needs CLIP; :func:`object_proposals` is pure geometry on ``(N, 3)`` positions and colours.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from abm.grounding.config import ProposalConfig  # the options live with the typed configurations


@dataclass
class Proposals:
    """Object candidates of one cloud.

    Attributes:
        candidates: point indices into the cloud, one array per candidate.
        kinds: ``"cluster"``, ``"part"`` (a colour part) or ``"without"`` (the cluster minus a support).
        cluster: index of the cluster each candidate comes from.
        table: ``(N,)`` bool, the points taken as table.
        table_height: the table top height used (m).
    """

    candidates: list[np.ndarray]
    kinds: list[str]
    cluster: list[int]
    table: np.ndarray
    table_height: float
    extra: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.candidates)


def estimate_table_height(z: np.ndarray, bin_size: float = 0.005) -> float:
    """The most common point height (m): the table top, which holds most points of a tabletop scene."""
    z = np.asarray(z, np.float64)
    if z.size == 0:
        return 0.0
    edges = np.arange(z.min(), z.max() + 2 * bin_size, bin_size)
    hist, edges = np.histogram(z, bins=edges)
    i = int(hist.argmax())
    in_bin = z[(z >= edges[i]) & (z <= edges[i + 1])]
    return float(np.median(in_bin))


def _cells(xyz: np.ndarray, voxel: float) -> np.ndarray:
    return np.floor(xyz / voxel).astype(np.int64)


def voxel_clusters(xyz: np.ndarray, voxel: float) -> NDArray[np.int64]:
    """``(N,)`` cluster id of every point: 26-connected components of the occupied ``voxel`` cells."""
    if len(xyz) == 0:
        return np.zeros(0, np.int64)
    cells = _cells(xyz, voxel)
    cells -= cells.min(0)
    grid = np.zeros(cells.max(0) + 1, bool)
    grid[tuple(cells.T)] = True
    labels, _ = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    clusters: NDArray[np.int64] = labels[tuple(cells.T)].astype(np.int64) - 1
    return clusters


def same_colour(a: np.ndarray, b: np.ndarray, tol: float, shade: float = 2.0) -> NDArray[np.bool_]:
    """``(K,)`` bool: colours ``a`` and ``b`` ``(K, 3)`` in ``[0, 1]`` are one surface's. Shading changes the
    brightness, not the hue: the chromaticities (``rgb / sum``) must agree within ``tol`` per channel and the
    brightnesses within a factor ``shade``; two dark colours (mean below 0.1) agree."""
    sa, sb = a.sum(1) + 1e-6, b.sum(1) + 1e-6
    chroma = np.abs(a / sa[:, None] - b / sb[:, None]).max(1) <= tol
    bright = np.abs(np.log(sa / sb)) <= np.log(shade)
    dark = (sa < 0.3) & (sb < 0.3)
    same: NDArray[np.bool_] = (chroma & bright) | dark
    return same


def color_parts(xyz: np.ndarray, rgb: np.ndarray, voxel: float, tol: float) -> NDArray[np.int32]:
    """``(M,)`` part id of the points of one cluster: neighbouring cells (26-connectivity) are joined when
    their mean colours are one surface's (:func:`same_colour` with chromaticity tolerance ``tol``)."""
    cells = _cells(xyz, voxel)
    cells -= cells.min(0) - 1
    dims = cells.max(0) + 2
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    uniq, inverse = np.unique(keys, return_inverse=True)
    n = len(uniq)
    counts = np.bincount(inverse, minlength=n).astype(np.float64)
    colour = np.stack([np.bincount(inverse, weights=rgb[:, c], minlength=n) for c in range(3)], 1) / counts[:, None]
    rows: list[NDArray[np.intp]] = []
    cols: list[NDArray[np.intp]] = []
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)]
    for a, b, c in offsets:
        shifted = uniq + (a * dims[1] + b) * dims[2] + c
        pos = np.clip(np.searchsorted(uniq, shifted), 0, n - 1)
        hit = uniq[pos] == shifted
        src, dst = np.nonzero(hit)[0], pos[hit]
        close = same_colour(colour[src], colour[dst], tol)
        rows.append(src[close])
        cols.append(dst[close])
    r, k = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r)), (r, k)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    parts: NDArray[np.int32] = labels[inverse]  # scipy's component labels are int32
    return parts


# The Panda hand in the tool-centre-point frame (+z out of the fingers, the fingers closing along y), in metres.
PALM_FRONT = 0.02        # the palm's front face is this far behind the TCP (measured in the rendered cloud)
FINGER_BASE = 0.045      # the fingers start this far behind the TCP
HAND_RADIUS = 0.15       # the palm and wrist lie within this distance of the gripper axis (the hand is 20 cm wide)
FINGER_TIP = 0.012       # the finger tips reach this far in front of the TCP
FINGER_HALF_WIDTH = 0.012
FINGER_THICKNESS = 0.025  # from a finger's inner face outwards
MAX_OPENING = 0.08       # finger gap at gripper_open = 1


def hand_points(xyz: np.ndarray, gripper_pose: np.ndarray, gripper_open: float) -> NDArray[np.bool_]:
    """``(N,)`` the points of ``xyz`` ``(N, 3)`` (m) on the Panda hand: the palm and wrist (behind the palm's
    front face, near the gripper axis) and the two fingers at the opening ``gripper_open`` (0 closed .. 1 open);
    ``gripper_pose`` ``(4, 4)`` is the tool centre point's pose (to world). What the fingers hold stays."""
    local: NDArray[np.float64] = (np.asarray(xyz, np.float64) - gripper_pose[:3, 3]) @ gripper_pose[:3, :3]
    x, y, z = local[:, 0], np.abs(local[:, 1]), local[:, 2]
    palm = (z < -PALM_FRONT) & (np.hypot(x, local[:, 1]) < HAND_RADIUS)
    inner = 0.5 * MAX_OPENING * float(np.clip(gripper_open, 0.0, 1.0)) - 0.003
    fingers = (z >= -FINGER_BASE) & (z < FINGER_TIP) & (np.abs(x) < FINGER_HALF_WIDTH) & (y > inner) & \
        (y < inner + FINGER_THICKNESS)
    hand: NDArray[np.bool_] = palm | fingers
    return hand


def object_proposals(xyz: np.ndarray, rgb: np.ndarray, config: ProposalConfig | None = None,
                     gripper_pose: np.ndarray | None = None, gripper_open: float = 1.0) -> Proposals:
    """Object candidates of a fused cloud (see the module docstring); ``gripper_pose`` ``(4, 4)`` (TCP to
    world) and ``gripper_open`` let ``config.hand_filter`` leave out the hand's points."""
    config = config or ProposalConfig()
    xyz = np.asarray(xyz, np.float64)
    rgb = np.asarray(rgb, np.float64)
    height = config.table_height if config.table_height is not None else estimate_table_height(xyz[:, 2])
    table = xyz[:, 2] <= height + config.table_margin
    keep = ~table
    if config.hand_filter and gripper_pose is not None:
        keep &= ~hand_points(xyz, np.asarray(gripper_pose, np.float64), gripper_open)
    above = np.nonzero(keep)[0]
    labels = voxel_clusters(xyz[above], config.voxel)
    sizes = np.bincount(labels) if len(labels) else np.zeros(0, np.int64)
    candidates: list[np.ndarray] = []
    kinds: list[str] = []
    cluster_of: list[int] = []
    for ci in np.argsort(-sizes, kind="stable"):
        if sizes[ci] < config.min_points or len(candidates) >= config.max_candidates:
            break
        members = above[labels == ci]
        candidates.append(members)
        kinds.append("cluster")
        cluster_of.append(int(ci))
        if not config.split:
            continue
        parts = color_parts(xyz[members], rgb[members], config.voxel, config.color_tol)
        part_sizes = np.bincount(parts)
        if len(part_sizes) < 2:
            continue
        for pi in np.argsort(-part_sizes, kind="stable"):
            size = part_sizes[pi]
            if size < config.min_points or len(candidates) >= config.max_candidates:
                break
            if size <= 0.9 * len(members):
                candidates.append(members[parts == pi])
                kinds.append("part")
                cluster_of.append(int(ci))
            rest = len(members) - size
            if size >= config.support_share * len(members) and rest >= config.min_points and \
                    len(candidates) < config.max_candidates:
                candidates.append(members[parts != pi])
                kinds.append("without")
                cluster_of.append(int(ci))
    return Proposals(candidates, kinds, cluster_of, table, float(height))


def with_base_points(xyz: np.ndarray, rgb: np.ndarray, members: np.ndarray, table: np.ndarray,
                     voxel: float, color_tol: float) -> np.ndarray:
    """``members`` plus the table-height points within ``voxel`` of them that have their colour."""
    low = np.nonzero(table)[0]
    if not len(members) or not len(low):
        return members
    # only the table points in the members' box grown by one voxel can be within a voxel of them
    box = xyz[members]
    near_box = np.all((xyz[low] >= box.min(0) - voxel) & (xyz[low] <= box.max(0) + voxel), axis=1)
    low = low[near_box]
    if not len(low):
        return members
    dist, index = cKDTree(xyz[members]).query(xyz[low], distance_upper_bound=voxel)
    near = np.isfinite(dist)
    same = np.zeros_like(near)
    same[near] = same_colour(rgb[low[near]], rgb[members[index[near]]], color_tol)
    return np.union1d(members, low[same])
