"""CLIP Feature Cloud: nearest-patch upsampling and lifting of features to the right 3-D points."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abm.geometry import Workspace, fuse_cameras, project_to_camera
from abm.grounding.feature_cloud import (
    build_feature_cloud,
    lift_patch_features,
    nearest_patch_index,
    patch_index_map,
    upsample_nearest,
)
from abm.render.synthetic import synthetic_scene
from abm.types import CameraFrame, Observation


class ColorBackbone:
    """A stand-in backbone whose patch feature is the mean colour of the patch (plus patch coordinates)."""

    def __init__(self, patch: int) -> None:
        self.patch = patch

    def dense_features(self, images, input_size=None):
        out = []
        for img in images:
            t = torch.from_numpy(np.asarray(img)).float() / 255.0  # (H, W, 3)
            h, w = t.shape[0] // self.patch, t.shape[1] // self.patch
            pooled = t[: h * self.patch, : w * self.patch].reshape(h, self.patch, w, self.patch, 3).mean((1, 3))
            rows, cols = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
            out.append(torch.cat([pooled, rows[..., None].float(), cols[..., None].float()], -1))
        return torch.stack(out)


def test_nearest_patch_index_is_exact():
    # 128 pixels onto a 24-patch grid (ViT-L/14 at 336): pixel centre (r + 0.5) * 336 / 128 lies in patch
    # floor(that / 14).
    idx = nearest_patch_index(128, 24)
    expected = np.floor((np.arange(128) + 0.5) * (336 / 128) / 14).astype(int)
    np.testing.assert_array_equal(idx, expected)
    np.testing.assert_array_equal(nearest_patch_index(8, 4), [0, 0, 1, 1, 2, 2, 3, 3])
    assert idx.min() == 0 and idx.max() == 23


def test_upsample_nearest_copies_patches_exactly():
    grid = torch.randn(2, 3, 4, 5)
    up = upsample_nearest(grid, 6, 8)
    assert up.shape == (2, 6, 8, 5)
    for r in range(6):
        for c in range(8):
            assert torch.equal(up[:, r, c], grid[:, r // 2, c // 2])
    # no blending: every upsampled vector is one of the patch vectors
    flat = grid.reshape(2, 12, 5)
    for b in range(2):
        same = (up[b].reshape(-1, 1, 5) == flat[b][None]).all(-1)
        assert same.any(-1).all()


def test_patch_index_map_matches_upsampling():
    grid = torch.randn(3, 5, 7)
    up = upsample_nearest(grid, 16, 16)
    idx = patch_index_map(16, 16, 3, 5)
    torch.testing.assert_close(up, grid.reshape(15, 7)[torch.from_numpy(idx)])


def _two_camera_scene():
    obs, names = synthetic_scene(seed=3, resolution=64)
    cams = {n: obs.cameras[n] for n in ("front", "wrist")}
    return Observation(cams, 1.0), names


def test_lifted_features_sit_at_the_right_points():
    obs, names = _two_camera_scene()
    cloud = fuse_cameras(obs, Workspace())
    assert set(np.unique(cloud.camera_index)) == {0, 1}
    # full-resolution "features" = the pixel colour: every point must get its own pixel's colour
    fc = build_feature_cloud(ColorBackbone(patch=1), obs, cloud=cloud)
    np.testing.assert_allclose(fc.features[:, :3], cloud.rgb, atol=1e-6)
    # coarse grid: the patch a point's feature came from is the one containing its re-projection
    fc = build_feature_cloud(ColorBackbone(patch=8), obs, cloud=cloud)
    for ci, name in enumerate(cloud.camera_names):
        frame = obs.camera(name)
        sel = cloud.camera_index == ci
        uvz = project_to_camera(cloud.xyz[sel], frame.intrinsics, frame.extrinsics)
        rows = np.floor(uvz[:, 1] + 0.5).astype(int) // 8
        cols = np.floor(uvz[:, 0] + 0.5).astype(int) // 8
        np.testing.assert_array_equal(fc.features[sel, 3], rows)
        np.testing.assert_array_equal(fc.features[sel, 4], cols)


def test_points_with_an_objects_colour_lie_on_that_object():
    obs, names = _two_camera_scene()
    cloud = fuse_cameras(obs, Workspace())
    seg = cloud.gather({n: f.segmentation for n, f in obs.cameras.items()})
    fc = build_feature_cloud(ColorBackbone(patch=1), obs, cloud=cloud)
    for obj_id in names:
        obj = seg == obj_id
        colours, counts = np.unique(cloud.rgb[obj], axis=0, return_counts=True)
        colour = colours[counts.argmax()]  # the colour of the object's most visible face
        close = np.all(fc.features[:, :3] == colour, axis=1)
        lo, hi = cloud.xyz[obj].min(0) - 0.005, cloud.xyz[obj].max(0) + 0.005
        inside = np.all((cloud.xyz[close] >= lo) & (cloud.xyz[close] <= hi), axis=1)
        assert close.sum() >= 5 and inside.all()
        # both cameras contribute points of the object
        assert set(np.unique(cloud.camera_index[obj])) == {0, 1}


def test_lift_checks_cameras():
    obs, _ = _two_camera_scene()
    cloud = fuse_cameras(obs, Workspace())
    with pytest.raises(KeyError, match="wrist"):
        lift_patch_features(cloud, {"front": np.zeros((4, 4, 2))}, {"front": (64, 64)})


def test_no_valid_depth_is_a_clear_error():
    obs, _ = _two_camera_scene()
    blank = {n: CameraFrame(f.rgb, np.zeros_like(f.depth), f.intrinsics, f.extrinsics) for n, f in obs.cameras.items()}
    with pytest.raises(ValueError, match="depth"):
        build_feature_cloud(ColorBackbone(patch=8), Observation(blank, 1.0))
