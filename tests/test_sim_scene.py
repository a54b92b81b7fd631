"""ABM-Bench core: scene building, camera calibration against the simulator, IK and motion execution."""

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator()

import abm.sim.cameras as cameras_module  # noqa: E402
from abm.evaluation.results import failure_reason  # noqa: E402
from abm.geometry import depth_to_points, fuse_cameras, matrix_to_quat  # noqa: E402
from abm.sim.catalog import catalog_entry  # noqa: E402
from abm.sim.scene import CAMERA_NAMES, PlacedObject, SceneSpec  # noqa: E402
from abm.sim.simulation import Simulation  # noqa: E402
from abm.sim.tasks.base import top_down_pose  # noqa: E402
from abm.types import KeyframeAction, Observation  # noqa: E402

BLOCK = "red block"


@pytest.fixture(scope="module")
def sim():
    scene = SceneSpec([PlacedObject("target", 0.6, -0.2), PlacedObject(BLOCK, 0.5, 0.04, yaw=0.4),
                       PlacedObject("green block", 0.4, 0.25)])
    s = Simulation(scene, resolution=64)
    yield s
    s.close()


def test_scene_builds_steps_and_objects_rest_on_table(sim):
    sim.reset()
    z0 = sim.object_pose(BLOCK)[2, 3]
    sim.step_seconds(0.2)
    assert abs(sim.object_pose(BLOCK)[2, 3] - z0) < 1e-3
    assert abs(z0 - catalog_entry(BLOCK).size[2]) < 2e-3  # resting on the table top z = 0
    assert sim.data.time > 0


def test_observation_contract(sim):
    sim.reset()
    obs = sim.observe()
    assert isinstance(obs, Observation)
    assert list(obs.cameras) == list(CAMERA_NAMES)
    for frame in obs.cameras.values():
        assert frame.rgb.shape == (64, 64, 3) and frame.depth.dtype == np.float32
        assert np.allclose(frame.intrinsics[:2, 2], [31.5, 31.5])
        assert set(np.unique(frame.segmentation)) <= {-1, 0, 1, 2}
    assert obs.gripper_open == pytest.approx(1.0, abs=0.02)
    assert np.allclose(obs.gripper_pose, sim.robot.tcp_pose())


def test_depth_and_segmentation_from_one_draw_equal_the_renderers_two_draws(sim, monkeypatch):
    sim.reset()
    sim.step_seconds(0.05)
    first = sim.observe()
    rig = sim.cameras
    assert rig.one_pass is True  # the first frame checked it against mujoco.Renderer's own modes
    rig.one_pass = False  # force the renderer's two draws
    again = sim.observe()
    rig.one_pass = True
    for name in CAMERA_NAMES:
        a, b = first.cameras[name], again.cameras[name]
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.segmentation, b.segmentation)
        assert np.array_equal(a.rgb, b.rgb) and (a.depth > 0).mean() > 0.5
    rig.one_pass = None  # a mismatch (here: a crafted one) keeps the two draws
    real = cameras_module._one_pass_depth_and_segmentation
    monkeypatch.setattr(cameras_module, "_one_pass_depth_and_segmentation",
                        lambda r, m: (lambda d, s: (d + 1e-3, s))(*real(r, m)))
    sim.observe()
    assert rig.one_pass is False


@pytest.mark.parametrize("camera", CAMERA_NAMES)
def test_deprojected_object_points_lie_on_its_simulated_pose(sim, camera):
    sim.reset()
    frame = sim.observe().cameras[camera]
    index = sim.object_index(BLOCK)
    mask = frame.segmentation == index
    assert mask.sum() >= 5, f"{camera} does not see the block"
    depth = np.where(mask, frame.depth, 0.0)
    points, _ = depth_to_points(depth, frame.intrinsics, frame.extrinsics)
    pose = sim.object_pose(index)
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    half = np.asarray(catalog_entry(BLOCK).size)
    # every point lies on the block's box, within 1 cm
    outside = np.clip(np.abs(local) - half, 0.0, None)
    assert np.linalg.norm(outside, axis=1).max() < 0.01
    # and on its surface: at least one coordinate at the box boundary
    assert np.abs(np.abs(local) - half).min(axis=1).max() < 0.01


def test_fused_cloud_segmentation_matches_object(sim):
    sim.reset()
    obs = sim.observe()
    cloud = fuse_cameras(obs)
    seg = cloud.gather({n: f.segmentation for n, f in obs.cameras.items()})
    block = cloud.xyz[seg == sim.object_index(BLOCK)]
    center = sim.object_pose(BLOCK)[:3, 3]
    assert np.linalg.norm(block.mean(0) - center) < 0.02
    table = cloud.xyz[(seg == -1) & (np.abs(cloud.xyz[:, 1]) < 0.4) & (cloud.xyz[:, 0] > 0.3)
                      & (cloud.xyz[:, 0] < 0.9)]
    assert np.median(np.abs(table[:, 2])) < 0.005  # the table top is z = 0


def test_ik_and_execution_reach_a_reachable_pose(sim):
    sim.reset()
    pose = top_down_pose(np.array([0.45, -0.1, 0.2]), 0.3)
    action = KeyframeAction(pose[:3, 3], matrix_to_quat(pose[:3, :3]), gripper_open=True, ignore_collision=False)
    result = sim.execute(action)
    assert result.status == "reached", result.message
    assert np.linalg.norm(sim.robot.tcp_pose()[:3, 3] - pose[:3, 3]) < 0.005
    assert result.rotation_error_deg < 2.0
    # straight Cartesian move
    pose[:3, 3] = [0.55, 0.1, 0.12]
    result = sim.execute(KeyframeAction(pose[:3, 3], matrix_to_quat(pose[:3, :3]), False, True))
    assert result.status == "reached", result.message
    assert np.linalg.norm(sim.robot.tcp_pose()[:3, 3] - pose[:3, 3]) < 0.005
    assert sim.robot.gripper_opening() < 0.05


def test_unreachable_target_returns_failure_without_moving(sim):
    sim.reset()
    before = sim.robot.arm_q
    action = KeyframeAction(np.array([1.6, 0.0, 0.3]), np.array([1.0, 0.0, 0.0, 0.0]), True)
    result = sim.execute(action)
    assert result.status == "unreachable" and not result.ok
    assert "no IK solution" in result.message
    assert np.allclose(sim.robot.arm_q, before, atol=1e-3)


def test_a_straight_move_into_the_table_is_blocked_and_leaves_the_gripper_alone(sim):
    sim.reset()
    pose = top_down_pose(np.array([0.45, -0.15, -0.04]), 0.0)  # 4 cm into the table, no collision checks
    result = sim.execute(KeyframeAction(pose[:3, 3], matrix_to_quat(pose[:3, :3]), False, True))
    assert result.status == "blocked" and not result.ok, result.message
    assert result.position_error > 0.01 and "target not reached" in result.message
    assert sim.robot.tcp_pose()[2, 3] > -0.01  # the table stopped it
    assert sim.robot.gripper_opening() > 0.9  # not closed: a stopped motion does not actuate the gripper
    assert failure_reason(False, "", ["reached", result.status], False) == "motion blocked"


def test_pushing_into_the_table_is_reported_as_collision(sim):
    sim.reset()
    pose = top_down_pose(np.array([0.45, -0.15, -0.03]), 0.0)  # fingertips 2 cm into the table
    result = sim.execute(KeyframeAction(pose[:3, 3], matrix_to_quat(pose[:3, :3]), True, False))
    assert result.status == "collided" and "table" in result.contacts
