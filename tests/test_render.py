"""Orthographic renderer: known pixels and depths, occlusion, round trips, channels, errors."""

import numpy as np
import pytest
import torch

from abm.geometry import Workspace, fuse_cameras
from abm.render import OrthographicRenderer, binarize_mask, center_pixel_mask, soft_mask
from abm.render.synthetic import synthetic_scene

WS = Workspace(center=(0.5, 0.0, 0.35), size=1.0)


def single_point_views(point, res=100):
    r = OrthographicRenderer(WS, resolution=res)
    out = r.render(torch.tensor([point], dtype=torch.float32), torch.tensor([[0.2, 0.4, 0.6]]))
    return r, out


def test_known_point_lands_on_expected_pixel_and_depth():
    # cube x in [0, 1], y in [-0.5, 0.5], z in [-0.15, 0.85]; 100 px -> 1 cm per pixel
    point = [0.705, 0.205, 0.105]
    r, out = single_point_views(point)
    # (row, col, depth) per view, from the axes in docs/conventions.md
    expected = {
        "front": (74, 70, 0.295),   # right=+y, down=-z, looks along -x from x=1
        "back": (74, 29, 0.705),    # right=-y, looks along +x from x=0
        "left": (74, 29, 0.295),    # right=-x, looks along -y from y=0.5
        "right": (74, 70, 0.705),   # right=+x, looks along +y from y=-0.5
        "top": (29, 29, 0.745),     # right=-y, down=-x, looks down from z=0.85
    }
    for vi, view in enumerate(r.views):
        occ = out.occupied[0, vi]
        assert occ.sum() == 1, view
        row, col = map(int, torch.nonzero(occ)[0])
        assert (row, col) == expected[view][:2], view
        assert out.depth[0, vi, 0, row, col].item() == pytest.approx(expected[view][2], abs=1e-5)
        np.testing.assert_allclose(out.xyz[0, vi, :, row, col].numpy(), point, atol=1e-6)
        np.testing.assert_allclose(out.rgb[0, vi, :, row, col].numpy(), [0.2, 0.4, 0.6])
    # background: rgb/xyz 0, depth = cube size
    assert out.rgb[0, 0, :, 0, 0].abs().sum() == 0
    assert out.depth[0, 0, 0, 0, 0].item() == pytest.approx(1.0)


@pytest.mark.parametrize("views", [("front", "back", "left", "right", "top"), ("top", "right", "front")])
def test_each_point_lands_on_the_pixel_project_gives(views):
    """render() places a point at the rounded pixel of project() in every view (its own arithmetic on the signed
    world axes must agree with the projection's matrix product, on pixel borders too)."""
    r = OrthographicRenderer(Workspace(center=(0.3, -0.1, 0.2), size=0.64), resolution=32, views=views)
    gen = torch.Generator().manual_seed(3)
    pts = (torch.rand(300, 1, 3, generator=gen) - 0.5) * 0.64 + r.center  # one point per batch entry
    pts[:100] = torch.round(pts[:100] / 0.01) * 0.01 + 0.005  # 1 cm grid + 0.5 cm: pixel borders of 2 cm pixels
    out = r.render(pts, torch.ones(300, 1, 3))
    uv, _ = r.project(pts[:, 0])  # (300, V, 2)
    inside = ((pts[:, 0] >= r.center - r.half) & (pts[:, 0] <= r.center + r.half)).all(-1)
    assert int(inside.sum()) > 250
    for i in torch.nonzero(inside)[:, 0].tolist():
        for vi in range(len(views)):
            col, row = torch.floor(uv[i, vi] + 0.5).int().clamp(0, 31).tolist()
            assert out.occupied[i, vi].sum() == 1 and bool(out.occupied[i, vi, row, col]), (i, views[vi])


def test_nearer_point_occludes_farther_one_in_every_view():
    # two points on the line of sight of each view: render both orders, the nearer always wins
    r = OrthographicRenderer(WS, resolution=64)
    center = torch.tensor(WS.center, dtype=torch.float32)
    for vi, _view in enumerate(r.views):
        forward = r.axes[vi, 2]
        near, far = center - 0.2 * forward, center + 0.2 * forward
        for pts, colors in (([near, far], [[1.0, 0, 0], [0, 0, 1.0]]), ([far, near], [[0, 0, 1.0], [1.0, 0, 0]])):
            out = r.render(torch.stack(pts), torch.tensor(colors))
            occ = out.occupied[0, vi]
            assert occ.sum() == 1
            row, col = map(int, torch.nonzero(occ)[0])
            assert out.rgb[0, vi, :, row, col].tolist() == [1.0, 0.0, 0.0]
            assert out.depth[0, vi, 0, row, col].item() == pytest.approx(0.3, abs=1e-5)


def test_project_unproject_round_trip_within_half_pixel():
    r = OrthographicRenderer(WS, resolution=220)
    pts = torch.from_numpy(np.random.default_rng(0).uniform(WS.lower, WS.upper, (1000, 3))).float()
    uv, depth = r.project(pts)
    assert uv.shape == (1000, 5, 2) and depth.shape == (1000, 5)
    back = r.unproject(uv, depth)
    np.testing.assert_allclose(back.numpy(), pts[:, None].expand(-1, 5, -1).numpy(), atol=1e-5)
    # through the discrete pixel of the rendered image: within half a pixel (and exact depth)
    pix = torch.floor(uv + 0.5)
    snapped = r.unproject(pix, depth)
    err = (snapped - pts[:, None]).norm(dim=-1)
    assert err.max().item() <= np.sqrt(2) * 0.5 * WS.size / 220 + 1e-6


def test_batch_matches_single_and_padding_is_ignored():
    obs, names = synthetic_scene(seed=1, resolution=48)
    cloud = fuse_cameras(obs, WS)
    r = OrthographicRenderer(WS, resolution=64, splat_radius=1)
    xyz, rgb = torch.from_numpy(cloud.xyz), torch.from_numpy(cloud.rgb)
    single = r.render(xyz, rgb)
    n = len(cloud)
    pad_xyz = torch.cat([xyz, torch.full((10, 3), 0.5)])  # padding inside the cube: must not show
    pad_rgb = torch.cat([rgb, torch.ones(10, 3)])
    valid = torch.cat([torch.ones(n, dtype=torch.bool), torch.zeros(10, dtype=torch.bool)])
    batch = r.render(torch.stack([pad_xyz, pad_xyz.flip(0)]), torch.stack([pad_rgb, pad_rgb.flip(0)]),
                     valid=torch.stack([valid, valid.flip(0)]))
    torch.testing.assert_close(batch.rgb[0], single.rgb[0])
    torch.testing.assert_close(batch.depth[0], single.depth[0])
    # the reversed cloud may resolve exact depth ties to another point, but the depth is the same
    torch.testing.assert_close(batch.depth[1], single.depth[0], atol=1e-5, rtol=0)
    torch.testing.assert_close(batch.occupied[1], single.occupied[0])
    channels = batch.rvt_channels()
    assert channels.shape == (2, 5, 10, 64, 64)
    # pixel-location channels: view index, row and column in [-1, 1]
    assert channels[0, 0, 7].unique().tolist() == [-1.0] and channels[0, 4, 7].unique().tolist() == [1.0]
    assert channels[0, 0, 8, 0, 0] == -1 and channels[0, 0, 8, -1, 0] == 1 and channels[0, 0, 9, 0, -1] == 1


def test_extra_channels_share_visibility():
    # a red point in front of a blue one: extra channel follows the visible (red) point
    r = OrthographicRenderer(WS, resolution=32, views=("top",))
    pts = torch.tensor([[0.5, 0.0, 0.5], [0.5, 0.0, 0.1], [0.2, 0.2, 0.0]])
    extra = torch.tensor([[1.0, 7.0], [0.0, 3.0], [0.0, 5.0]])
    out = r.render(pts, torch.zeros(3, 3), extra=extra)
    assert out.extra.shape == (1, 1, 2, 32, 32)
    assert sorted(out.extra[0, 0, 1][out.occupied[0, 0]].tolist()) == [5.0, 7.0]
    assert out.extra[0, 0, 0].sum().item() == 1.0


def test_points_outside_cube_are_dropped_and_splat_covers_square():
    r = OrthographicRenderer(WS, resolution=50, splat_radius=2)
    out = r.render(torch.tensor([[0.5, 0.0, 0.35], [5.0, 0.0, 0.35]]), torch.ones(2, 3))
    assert out.occupied[0].sum(dim=(1, 2)).tolist() == [25] * 5


def test_bad_inputs_give_clear_errors():
    r = OrthographicRenderer(WS, resolution=16)
    with pytest.raises(ValueError, match="empty point cloud"):
        r.render(torch.zeros(0, 3), torch.zeros(0, 3))
    with pytest.raises(ValueError, match="points must be"):
        r.render(torch.zeros(5, 2), torch.zeros(5, 3))
    with pytest.raises(ValueError, match="rgb must have shape"):
        r.render(torch.zeros(5, 3), torch.zeros(4, 3))
    with pytest.raises(ValueError, match="extra must have shape"):
        r.render(torch.zeros(5, 3), torch.zeros(5, 3), extra=torch.zeros(5))
    with pytest.raises(ValueError, match="valid must have shape"):
        r.render(torch.zeros(5, 3), torch.zeros(5, 3), valid=torch.ones(4, dtype=torch.bool))
    with pytest.raises(ValueError, match="unknown views"):
        OrthographicRenderer(WS, views=("bottom",))


def test_center_pixel_mask():
    m = torch.zeros(3, 9, 9)
    m[0, 2:5, 3:8] = 0.8                      # rectangle: centre (3, 5)
    m[1, 0:9, 0:2] = 1.0                      # two bars: centroid (4, 4) falls between them
    m[1, 0:9, 7:9] = 1.0
    out = center_pixel_mask(m)
    assert out.shape == m.shape and out.sum(dim=(1, 2)).tolist() == [1.0, 1.0, 0.0]
    assert out[0, 3, 5] == 1.0
    row, col = map(int, torch.nonzero(out[1])[0])
    assert m[1, row, col] > 0 and row == 4  # snapped onto the region, level with the centroid
    batched = center_pixel_mask(m.view(1, 3, 9, 9))
    torch.testing.assert_close(batched[0], out)


def test_binarized_and_soft_masks():
    m = torch.tensor([[-0.2, 0.3], [0.6, 1.4]])
    assert binarize_mask(m).tolist() == [[0.0, 0.0], [1.0, 1.0]]
    assert binarize_mask(m, threshold=0.2).tolist() == [[0.0, 1.0], [1.0, 1.0]]
    torch.testing.assert_close(soft_mask(m), torch.tensor([[0.0, 0.3], [0.6, 1.0]]))
