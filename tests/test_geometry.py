"""Geometry: deprojection, fusion, workspace, rotation bins and SE(3) augmentation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from abm.geometry import (
    Workspace,
    augment_cloud,
    bins_to_quat,
    canonical_gripper_matrix,
    canonical_gripper_quat,
    depth_to_points,
    euler_to_quat,
    fuse_cameras,
    matrix_to_quat,
    project_to_camera,
    quat_angle_deg,
    quat_to_bins,
    quat_to_euler,
    quat_to_matrix,
    symmetric_angle_deg,
    transform_action,
)
from abm.render.synthetic import look_at, pinhole_intrinsics, synthetic_scene
from abm.types import CameraFrame, KeyframeAction


def plane_depth(normal, offset, intrinsics, extrinsics, res):
    """Analytic depth image of the plane n.x = offset."""
    rows, cols = np.mgrid[0:res, 0:res].astype(float)
    d_cam = np.stack([(cols - intrinsics[0, 2]) / intrinsics[0, 0],
                      (rows - intrinsics[1, 2]) / intrinsics[1, 1], np.ones_like(rows)], -1)
    d = d_cam @ extrinsics[:3, :3].T
    t = (offset - normal @ extrinsics[:3, 3]) / (d @ normal)
    return t.astype(np.float32)


def test_deprojected_tilted_plane_lies_on_plane():
    res = 64
    k = pinhole_intrinsics(res, 55.0)
    ext = look_at(np.array([0.9, 0.3, 0.7]), np.array([0.5, 0.0, 0.0]))
    normal = np.array([0.2, -0.1, 1.0])
    normal /= np.linalg.norm(normal)
    depth = plane_depth(normal, 0.05, k, ext, res)
    depth[0, 0], depth[1, 1], depth[2, 2] = 0.0, np.nan, np.inf
    points, pixels = depth_to_points(depth, k, ext)
    assert len(points) == res * res - 3
    assert not any((tuple(p) in {(0, 0), (1, 1), (2, 2)}) for p in pixels.tolist())
    assert np.abs(points @ normal - 0.05).max() < 1e-3
    # and projecting back lands on the source pixels
    uvz = project_to_camera(points, k, ext)
    np.testing.assert_allclose(uvz[:, 0], pixels[:, 1], atol=1e-6)
    np.testing.assert_allclose(uvz[:, 1], pixels[:, 0], atol=1e-6)


def test_fusion_keeps_provenance_and_crops_workspace():
    obs, names = synthetic_scene(seed=3, resolution=48)
    ws = Workspace()
    cloud = fuse_cameras(obs, ws)
    assert cloud.camera_names == list(obs.cameras)
    assert ws.contains(cloud.xyz).all()
    seg = cloud.gather({n: f.segmentation for n, f in obs.cameras.items()})
    # every block's points sit inside its 5 cm cube (to 2 mm)
    for idx in names:
        pts = cloud.xyz[seg == idx]
        assert len(pts) > 0
        assert np.ptp(pts, axis=0).max() < 0.052
    # colours come from the source pixels
    ci, (r, c) = cloud.camera_index[10], cloud.pixels[10]
    np.testing.assert_allclose(cloud.rgb[10] * 255, obs.cameras[cloud.camera_names[ci]].rgb[r, c], atol=1e-3)


def test_fusion_errors():
    obs, _ = synthetic_scene(seed=0, resolution=16)
    frames = dict(obs.cameras)
    with pytest.raises(KeyError, match="not in observation"):
        fuse_cameras(frames, camera_names=["front", "overhead"])
    f = frames["front"]
    empty = CameraFrame(f.rgb, np.zeros_like(f.depth), f.intrinsics, f.extrinsics)
    with pytest.raises(ValueError, match="no valid depth"):
        fuse_cameras({"front": empty})
    with pytest.raises(ValueError, match="inside the workspace"):
        fuse_cameras({"front": f}, Workspace(center=(10.0, 10.0, 10.0), size=0.5))
    with pytest.raises(KeyError, match="gather needs values"):
        fuse_cameras({"front": f}).gather({})


def test_workspace_normalisation_round_trip():
    ws = Workspace(center=(0.5, 0.0, 0.35), size=1.0)
    np.testing.assert_allclose(ws.normalize(ws.upper), [1, 1, 1])
    np.testing.assert_allclose(ws.normalize(ws.lower), [-1, -1, -1])
    p = np.random.default_rng(0).uniform(-1, 1, (10, 3))
    np.testing.assert_allclose(ws.normalize(ws.denormalize(p)), p)
    with pytest.raises(ValueError, match="size"):
        Workspace(size=0.0)


def test_rotation_conversions_agree():
    quats = Rotation.random(50, random_state=2).as_quat()
    np.testing.assert_allclose(quat_angle_deg(matrix_to_quat(quat_to_matrix(quats)), quats), 0, atol=1e-6)
    np.testing.assert_allclose(quat_angle_deg(euler_to_quat(quat_to_euler(quats)), quats), 0, atol=1e-6)


def test_rotation_bins_round_trip_within_half_bin():
    quats = Rotation.random(500, random_state=0).as_quat()
    bins = quat_to_bins(quats)
    assert bins.min() >= 0 and bins.max() < 72
    euler = quat_to_euler(quats)
    decoded = quat_to_euler(bins_to_quat(bins))
    # each decoded Euler angle is within 2.5 degrees of the original (modulo 360)
    diff = (decoded - euler + 180.0) % 360.0 - 180.0
    assert np.abs(diff).max() <= 2.5 + 1e-6
    # bins are stable: decoding then encoding gives the same bins back
    np.testing.assert_array_equal(quat_to_bins(bins_to_quat(bins)), bins)
    # the identity and a 90-degree yaw decode exactly
    assert quat_angle_deg(bins_to_quat(quat_to_bins([0, 0, 0, 1])), [0, 0, 0, 1]) < 1e-6
    yaw90 = euler_to_quat([0.0, 0.0, 90.0])
    assert quat_angle_deg(bins_to_quat(quat_to_bins(yaw90)), yaw90) < 1e-6


def test_augmentation_moves_points_and_action_together():
    ws = Workspace()
    rng = np.random.default_rng(0)
    points = rng.uniform(ws.lower + 0.3, ws.upper - 0.3, (100, 3)).astype(np.float32)
    grasp = Rotation.from_euler("xyz", [180, 0, 30], degrees=True).as_quat()
    action = KeyframeAction(points[7], grasp, gripper_open=False, ignore_collision=True)
    offset = np.array([0.0, 0.0, 0.1])  # a point fixed in the gripper frame, 10 cm along its z axis
    tip = action.matrix @ np.append(offset, 1)
    for _ in range(20):
        new_points, new_action, transform = augment_cloud(points, action, ws, rng)
        assert not np.allclose(transform, np.eye(4))
        np.testing.assert_allclose(new_action.position, new_points[7], atol=1e-5)
        np.testing.assert_allclose(new_action.matrix @ np.append(offset, 1), transform @ tip, atol=1e-5)
        assert ws.contains(new_action.position)
        assert new_action.gripper_open is False and new_action.ignore_collision is True
        yaw = np.degrees(np.arctan2(transform[1, 0], transform[0, 0]))
        assert abs(yaw) <= 45.0 + 1e-6
        np.testing.assert_allclose(transform[2, :3], [0, 0, 1], atol=1e-9)  # yaw only
        # rigid: pairwise distances preserved
        np.testing.assert_allclose(np.linalg.norm(new_points[0] - new_points[1]),
                                   np.linalg.norm(points[0] - points[1]), rtol=1e-5)


def test_transform_action_identity():
    a = KeyframeAction([0.4, 0.1, 0.2], [0, 1, 0, 0], True)
    b = transform_action(np.eye(4), a)
    np.testing.assert_allclose(b.position, a.position)
    # the same keyframe up to the gripper's 180-degree symmetry, returned in its canonical form
    assert symmetric_angle_deg(a.quaternion, b.quaternion, 2) < 1e-6
    assert quat_angle_deg(b.quaternion, canonical_gripper_quat(b.quaternion, 2)) < 1e-6


def _top_down(yaw_deg: float) -> np.ndarray:
    """TCP pointing down with the finger axis (TCP y) at world yaw ``yaw_deg``."""
    yaw = np.radians(yaw_deg)
    y = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return np.stack([np.cross(y, z), y, z], axis=1)


@pytest.mark.parametrize(("yaw", "symmetry", "expected"), [
    (100.0, 2, -80.0),    # 145° from the -45° reference -> its 180° turn
    (30.0, 2, 30.0),      # within ±90° already
    (-170.0, 2, 10.0),
    (60.0, 4, -30.0),     # square: within ±45°
    (-100.0, 4, -10.0),
    (123.0, 0, -45.0),    # round: always the reference
    (100.0, 1, 100.0),    # no symmetry: unchanged
])
def test_canonical_gripper_yaw(yaw, symmetry, expected):
    out = canonical_gripper_matrix(_top_down(yaw), symmetry)
    np.testing.assert_allclose(out[:, 2], [0.0, 0.0, -1.0], atol=1e-9)  # same gripper axis
    got = np.degrees(np.arctan2(out[1, 1], out[0, 1]))
    assert abs((got - expected + 180.0) % 360.0 - 180.0) < 1e-6, got
    # idempotent, and every member of the class maps to the same matrix
    np.testing.assert_allclose(canonical_gripper_matrix(out, symmetry), out, atol=1e-9)
    if symmetry > 1:
        turned = canonical_gripper_matrix(_top_down(yaw + 360.0 / symmetry), symmetry)
        np.testing.assert_allclose(turned, out, atol=1e-9)


def test_symmetric_angle_respects_symmetry():
    label = matrix_to_quat(_top_down(-45.0))
    for turn, sym, expected in ((180.0, 2, 0.0), (90.0, 2, 90.0), (90.0, 4, 0.0), (37.0, 0, 0.0), (30.0, 4, 30.0)):
        pred = matrix_to_quat(_top_down(-45.0 + turn))
        assert abs(symmetric_angle_deg(pred, label, sym) - expected) < 0.6, (turn, sym)
    with pytest.raises(ValueError, match="symmetry"):
        canonical_gripper_matrix(np.eye(3), -1)
