"""CLIP Feature Cloud: one MaskCLIP feature per 3-D point of a fused, workspace-cropped point cloud.

Each camera image goes through the backbone (all cameras in one batch), giving an ``h x w`` grid of
patch features. A pixel takes the feature of the patch that contains its centre (**nearest patch**, no
bilinear blending, so object boundaries stay sharp): for an image of ``H x W`` pixels resized as a whole
to the model's input, pixel ``(r, c)`` belongs to patch ``(floor((r + 0.5) h / H), floor((c + 0.5) w / W))``.
Points carry their source camera and pixel (:class:`abm.geometry.PointCloud`), so the per-pixel patch
index is attached with :meth:`~abm.geometry.PointCloud.gather` and the features are looked up per point,
without ever materialising the ``H x W x D`` upsampled maps.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
from numpy.typing import NDArray

from abm.geometry import PointCloud, Workspace, fuse_cameras
from abm.types import Observation


class DenseFeatureBackbone(Protocol):
    """What :func:`build_feature_cloud` needs of a backbone (:class:`~abm.grounding.clip.ClipBackbone` has it)."""

    def dense_features(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        """``(B, h, w, D)`` patch features of ``uint8`` ``(H, W, 3)`` images."""
        ...


def nearest_patch_index(size: int, grid: int) -> NDArray[np.int64]:
    """``(size,)`` int64: the patch (of ``grid`` along this axis) containing each pixel centre."""
    if size < 1 or grid < 1:
        raise ValueError(f"size and grid must be positive, got {size}, {grid}")
    return np.minimum(((np.arange(size) + 0.5) * grid / size).astype(np.int64), grid - 1)


def upsample_nearest(patch_features: torch.Tensor | np.ndarray, height: int, width: int) -> torch.Tensor:
    """Nearest-patch upsampling ``(..., h, w, D)`` -> ``(..., height, width, D)`` (exact copies of patches)."""
    feats = torch.as_tensor(patch_features)
    h, w = feats.shape[-3], feats.shape[-2]
    rows = torch.from_numpy(nearest_patch_index(height, h)).to(feats.device)
    cols = torch.from_numpy(nearest_patch_index(width, w)).to(feats.device)
    return feats.index_select(-3, rows).index_select(-2, cols)


def patch_index_map(height: int, width: int, grid_h: int, grid_w: int, offset: int = 0) -> NDArray[np.int64]:
    """``(height, width)`` int64: flat index ``offset + i * grid_w + j`` of the nearest patch of each pixel."""
    rows = nearest_patch_index(height, grid_h)
    cols = nearest_patch_index(width, grid_w)
    index: NDArray[np.int64] = offset + rows[:, None] * grid_w + cols[None, :]
    return index


def lift_patch_features(
    cloud: PointCloud,
    patch_features: Mapping[str, np.ndarray | torch.Tensor],
    image_sizes: Mapping[str, tuple[int, int]],
) -> NDArray[np.float32]:
    """Attach per-camera patch grids to the points of ``cloud``.

    Args:
        cloud: fused point cloud (its :attr:`~abm.geometry.PointCloud.camera_names` must all be present).
        patch_features: camera name -> ``(h, w, D)`` patch features of that camera image.
        image_sizes: camera name -> ``(H, W)`` of the original camera image in pixels.

    Returns:
        ``(N, D)`` float32: the nearest-patch feature at every point's source pixel.
    """
    table, index = lift_patch_index(cloud, patch_features, image_sizes)
    features: NDArray[np.float32] = table[index]
    return features


def lift_patch_index(
    cloud: PointCloud,
    patch_features: Mapping[str, np.ndarray | torch.Tensor],
    image_sizes: Mapping[str, tuple[int, int]],
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """:func:`lift_patch_features` without the ``(N, D)`` array: the cameras' patches stacked into one table
    ``(P, D)`` float32 (camera after camera in ``cloud.camera_names`` order, row-major within a grid) and each
    point's row in it ``(N,)`` int64, so that ``table[index]`` is :func:`lift_patch_features`' result."""
    missing = [n for n in cloud.camera_names if n not in patch_features]
    if missing:
        raise KeyError(f"no patch features for cameras {missing}; got {sorted(patch_features)}")
    flats, index_maps, offset = [], {}, 0
    for name in cloud.camera_names:
        grid = np.asarray(torch.as_tensor(patch_features[name]).float().cpu())
        gh, gw, d = grid.shape
        height, width = image_sizes[name]
        index_maps[name] = patch_index_map(height, width, gh, gw, offset)
        flats.append(grid.reshape(gh * gw, d))
        offset += gh * gw
    table = np.concatenate(flats).astype(np.float32, copy=False)
    return table, np.asarray(cloud.gather(index_maps), np.int64)


@dataclass(frozen=True)
class LiftedFeatures:
    """Per-point features kept as the patch table they were lifted from (:func:`lift_patch_index`): point ``i``'s
    feature is ``table[index[i]]``. Indexing gives the rows of the ``(N, D)`` array without building it (a
    scene's ~50k points share ~1000 patches, so the table is ~50x smaller than the array).

    Attributes:
        table: ``(P, D)`` patch features, float32 (float16 when read from a grounding cache).
        index: ``(N,)`` int64 row of each point.
    """

    table: NDArray[np.floating]
    index: NDArray[np.int64]

    @classmethod
    def per_point(cls, features: NDArray[np.floating]) -> LiftedFeatures:
        """``(N, D)`` features as a table of their own: one row per point (features that are no lookup, e.g. a
        mean over several input scales)."""
        return cls(features, np.arange(len(features), dtype=np.int64))

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, rows: NDArray[np.intp]) -> NDArray[np.floating]:
        picked: NDArray[np.floating] = self.table[self.index[rows]]
        return picked

    def dense(self) -> NDArray[np.floating]:
        """The ``(N, D)`` array ``table[index]``."""
        features: NDArray[np.floating] = self.table[self.index]
        return features

    def compact(self) -> LiftedFeatures:
        """The same features with only the rows some point uses, in table order (what a cache stores)."""
        used, index = np.unique(self.index, return_inverse=True)
        return LiftedFeatures(self.table[used], index.astype(np.int64).reshape(-1))


@dataclass
class FeatureCloud:
    """A point cloud with one CLIP feature per point.

    Attributes:
        cloud: the fused, workspace-cropped :class:`~abm.geometry.PointCloud` (``N`` points).
        features: ``(N, D)`` float32 unit-length MaskCLIP features.
        patch_features: camera name -> ``(h, w, D)`` patch grid the features came from.
    """

    cloud: PointCloud
    features: np.ndarray
    patch_features: dict[str, np.ndarray]


def build_feature_cloud(
    backbone: DenseFeatureBackbone,
    observation: Observation,
    workspace: Workspace | None = None,
    cloud: PointCloud | None = None,
    camera_names: Sequence[str] | None = None,
) -> FeatureCloud:
    """Run the backbone on every camera (one batch), then lift and fuse the features.

    Args:
        backbone: a :class:`~abm.grounding.clip.ClipBackbone` (anything with ``dense_features(images)``).
        observation: the RGB-D frames.
        workspace: crop (default :class:`~abm.geometry.Workspace`); ignored when ``cloud`` is given.
        cloud: an already fused cloud of ``observation`` to attach the features to.
        camera_names: cameras to use when fusing (default all).
    """
    if cloud is None:
        cloud = fuse_cameras(observation, workspace or Workspace(), camera_names)
    frames = [observation.camera(n) for n in cloud.camera_names]
    grids = backbone.dense_features([f.rgb for f in frames])
    patch = {n: grids[i].float().cpu().numpy() for i, n in enumerate(cloud.camera_names)}
    sizes = {n: (f.height, f.width) for n, f in zip(cloud.camera_names, frames, strict=True)}
    return FeatureCloud(cloud, lift_patch_features(cloud, patch, sizes), patch)
