"""Real-hardware adapters with fake SDKs: RealSense cameras (pyrealsense2), the UR arm and grippers (ur_rtde),
building them from the robot YAML, and demonstrations recorded on a robot stored and trained as episodes."""

from __future__ import annotations

import dataclasses
import io
import json
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from abm.errors import ExternalError
from abm.robot import DryRunArm, LimitError, MotionLimits, RobotConfig, record_observations, run_robot
from abm.robot.calibration import save_calibration
from abm.robot.realsense import RealSenseCamera
from abm.robot.ur import DryRunGripper, URArm, URDigitalOutputGripper, pose_to_ur
from abm.types import KeyframeAction
from conftest import TINY_POLICY

OPEN = MotionLimits(workspace_lower=(-2.0, -2.0, -2.0), workspace_upper=(2.0, 2.0, 2.0), max_step_m=5.0,
                    max_tilt_deg=180.0)
DOWN_YAW_90 = Rotation.from_euler("xyz", [180.0, 0.0, 90.0], degrees=True)  # gripper down, turned 90 deg


# --------------------------------------------------------------------------------------------- fake pyrealsense2
def fake_realsense(connected: dict[str, tuple[int, int]], scale: float = 0.001) -> SimpleNamespace:
    """A fake ``pyrealsense2`` module: ``connected`` maps serial -> (raw depth value, red value) of its images.

    Unaligned frame sets carry depth 0; only ``align(stream.color).process`` gives the real depth, so a camera
    that skips alignment reads zeros."""
    log = SimpleNamespace(devices=[], streams=[], stopped=[], aligned_to=[])
    width = height = 6

    class Frame:
        def __init__(self, data: np.ndarray) -> None:
            self.data = data

        def __bool__(self) -> bool:
            return True

        def get_data(self) -> np.ndarray:
            return self.data

    class Frames:
        def __init__(self, serial: str, aligned: bool) -> None:
            self.serial, self.aligned = serial, aligned

        def get_depth_frame(self) -> Frame:
            raw = connected[self.serial][0] if self.aligned else 0
            return Frame(np.full((height, width), raw, np.uint16))

        def get_color_frame(self) -> Frame:
            rgb = np.zeros((height, width, 3), np.uint8)
            rgb[..., 0] = connected[self.serial][1]
            return Frame(rgb)

    class Config:
        def enable_device(self, serial: str) -> None:
            self.serial = serial
            log.devices.append(serial)

        def enable_stream(self, stream, w, h, fmt, fps) -> None:
            log.streams.append((stream, fmt, w, h, fps))

    intrinsics = SimpleNamespace(fx=500.0, fy=510.0, ppx=2.5, ppy=2.4, width=width, height=height)
    profile_of = {}

    class Pipeline:
        def start(self, config: Config):
            self.serial = config.serial
            stream_profile = SimpleNamespace(as_video_stream_profile=lambda: SimpleNamespace(
                get_intrinsics=lambda: intrinsics))
            sensor = SimpleNamespace(get_depth_scale=lambda: scale)
            profile_of[config.serial] = SimpleNamespace(
                get_device=lambda: SimpleNamespace(first_depth_sensor=lambda: sensor),
                get_stream=lambda stream: stream_profile if stream == "color" else None)
            return profile_of[config.serial]

        def wait_for_frames(self, timeout_ms: int) -> Frames:
            return Frames(self.serial, aligned=False)

        def stop(self) -> None:
            log.stopped.append(self.serial)

    class Align:
        def __init__(self, stream: str) -> None:
            log.aligned_to.append(stream)

        def process(self, frames: Frames) -> Frames:
            return Frames(frames.serial, aligned=True)

    devices = [SimpleNamespace(get_info=lambda key, s=s: s) for s in connected]
    return SimpleNamespace(
        camera_info=SimpleNamespace(serial_number="serial_number"),
        stream=SimpleNamespace(depth="depth", color="color"), format=SimpleNamespace(z16="z16", rgb8="rgb8"),
        context=lambda: SimpleNamespace(query_devices=lambda: devices), config=Config, pipeline=Pipeline,
        align=Align, log=log)


def _pose(position, rotation: Rotation) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation.as_matrix(), position
    return out


def test_realsense_camera_gives_metric_aligned_calibrated_frames(tmp_path) -> None:
    rs = fake_realsense({"111": (1500, 10), "222": (800, 20), "333": (1, 30)}, scale=0.001)
    front, left = _pose([1.2, 0.0, 0.6], Rotation.from_euler("y", -120, degrees=True)), np.eye(4)
    save_calibration(tmp_path / "cal.yaml", {"front": {"intrinsics": np.eye(3), "extrinsics": front},
                                             "222": {"intrinsics": np.eye(3), "extrinsics": left}})
    camera = RealSenseCamera({"front": "111", "left": "222"}, tmp_path / "cal.yaml", width=6, height=6, fps=15,
                             warmup_frames=2, rs_module=rs)
    assert rs.log.devices == ["111", "222"]  # only the configured serials, 333 stays off
    assert sorted(rs.log.streams) == sorted([("depth", "z16", 6, 6, 15), ("color", "rgb8", 6, 6, 15)] * 2)
    assert rs.log.aligned_to == ["color", "color"]
    frames = camera.read()
    assert list(frames) == ["front", "left"]
    np.testing.assert_allclose(frames["front"].depth, 1.5)  # 1500 raw * 0.001 m, aligned to colour
    np.testing.assert_allclose(frames["left"].depth, 0.8)
    assert frames["front"].depth.dtype == np.float32 and frames["left"].rgb[0, 0, 0] == 20
    np.testing.assert_allclose(frames["front"].intrinsics, [[500, 0, 2.5], [0, 510, 2.4], [0, 0, 1]])
    np.testing.assert_allclose(frames["front"].extrinsics, front, atol=1e-8)  # by name
    np.testing.assert_allclose(frames["left"].extrinsics, left)  # by serial
    assert camera.object_names == {} and frames["front"].segmentation is None
    camera.close()
    assert sorted(rs.log.stopped) == ["111", "222"]
    with pytest.raises(RuntimeError, match=r"\['999'\] not connected"):
        RealSenseCamera(["999"], None, rs_module=rs)
    with pytest.raises(ValueError, match="'top' .* not in the calibration file"):
        RealSenseCamera({"top": "333"}, tmp_path / "cal.yaml", rs_module=rs)


def test_missing_sdks_say_what_to_install(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    monkeypatch.setitem(sys.modules, "rtde_receive", None)
    with pytest.raises(ExternalError, match="pip install pyrealsense2"):
        RealSenseCamera(["1"])
    with pytest.raises(ExternalError, match="pip install ur_rtde"):
        URArm("10.0.0.2")


# ---------------------------------------------------------------------------------------------- fake ur_rtde
class FakeUR:
    """One fake controller behind fake ``rtde_control`` / ``rtde_receive`` / ``rtde_io`` modules."""

    def __init__(self, pose=(0.5, 0.0, 0.3, np.pi, 0.0, 0.0)) -> None:
        self.pose, self.outputs, self.calls, self.controls, self.progress = list(pose), [False] * 8, [], 0, []
        self.outcome = "reached"  # or "rejected", "stuck", "missed": what the next moveL does
        ur = self

        class Control:
            def __init__(self, host: str) -> None:
                ur.controls += 1

            def moveL(self, pose, speed, acceleration, asynchronous=False) -> bool:  # noqa: N802 - ur_rtde names
                ur.calls.append(("moveL", list(pose), speed, acceleration, asynchronous))
                if ur.outcome == "rejected":
                    return False
                ur.progress = [0] * (10**6 if ur.outcome == "stuck" else 2)  # running for some polls, then done
                ur.pose = list(pose) if ur.outcome != "missed" else [p + 0.01 for p in pose]
                return True

            def getAsyncOperationProgress(self) -> int:  # noqa: N802
                return ur.progress.pop() if ur.progress else -1

            def __getattr__(self, name: str):  # setTcp, stopL, stopScript, disconnect
                return lambda *args: ur.calls.append((name, *args))

        class Receive:
            def __init__(self, host: str) -> None:
                self.host = host

            def getActualTCPPose(self) -> list[float]:  # noqa: N802
                return list(ur.pose)

            def getDigitalOutState(self, output: int) -> bool:  # noqa: N802
                return ur.outputs[output]

            def disconnect(self) -> None:
                ur.calls.append(("receive.disconnect",))

        class IO:
            def __init__(self, host: str) -> None:
                pass

            def setStandardDigitalOut(self, output: int, level: bool) -> bool:  # noqa: N802
                ur.calls.append(("setStandardDigitalOut", output, level))
                ur.outputs[output] = level
                return True

        self.modules = {"rtde_control": SimpleNamespace(RTDEControlInterface=Control),
                        "rtde_receive": SimpleNamespace(RTDEReceiveInterface=Receive),
                        "rtde_io": SimpleNamespace(RTDEIOInterface=IO)}

    def moves(self) -> list:
        return [c for c in self.calls if c[0] == "moveL"]


def test_ur_arm_sends_the_rotation_vector_and_switches_the_gripper() -> None:
    ur = FakeUR()
    gripper = DryRunGripper()
    arm = URArm("10.0.0.2", gripper, speed=0.2, acceleration=0.5, rtde_control=ur.modules["rtde_control"],
                rtde_receive=ur.modules["rtde_receive"])
    quarter = Rotation.from_euler("z", 90, degrees=True)  # 90 deg about z: rotation vector (0, 0, pi/2)
    assert arm.move(KeyframeAction([0.5, 0.1, 0.3], quarter.as_quat(), False)) == "reached"
    _, pose, speed, acc, asynchronous = ur.moves()[-1]
    np.testing.assert_allclose(pose, [0.5, 0.1, 0.3, 0.0, 0.0, np.pi / 2], atol=1e-9)
    assert (speed, acc, asynchronous) == (0.2, 0.5, True) and gripper.commands == [False]
    arm.move(KeyframeAction([0.4, -0.1, 0.2], DOWN_YAW_90.as_quat(), True))
    np.testing.assert_allclose(ur.moves()[-1][1][3:], DOWN_YAW_90.as_rotvec(), atol=1e-9)
    assert gripper.commands == [False, True]
    state, opening = arm.state()
    np.testing.assert_allclose(state, _pose([0.4, -0.1, 0.2], DOWN_YAW_90), atol=1e-9)
    assert opening == 1.0
    arm.stop()
    arm.close()
    assert [c[0] for c in ur.calls[-4:]] == ["stopL", "stopScript", "disconnect", "receive.disconnect"]
    # abm's TCP 15 cm beyond the controller's: the controller's TCP goes 15 cm back along the approach axis (down)
    offset = URArm("h", DryRunGripper(), tcp_offset=[0, 0, 0.15, 0, 0, 0], rtde_control=ur.modules["rtde_control"],
                   rtde_receive=ur.modules["rtde_receive"])
    target = offset.target_pose(KeyframeAction([0.4, -0.1, 0.2], DOWN_YAW_90.as_quat(), True))
    np.testing.assert_allclose(target, [0.4, -0.1, 0.35, *DOWN_YAW_90.as_rotvec()], atol=1e-9)
    ur.pose = target
    np.testing.assert_allclose(offset.state()[0], _pose([0.4, -0.1, 0.2], DOWN_YAW_90), atol=1e-9)
    # the controller's base turned 180 deg about z in abm's base frame: targets are turned back
    turned = URArm("h", DryRunGripper(), base_pose=[0, 0, 0, 0, 0, np.pi], rtde_control=ur.modules["rtde_control"],
                   rtde_receive=ur.modules["rtde_receive"])
    expected = pose_to_ur(_pose([-0.4, 0.1, 0.2], Rotation.from_euler("z", 180, degrees=True) * DOWN_YAW_90))
    np.testing.assert_allclose(turned.target_pose(KeyframeAction([0.4, -0.1, 0.2], DOWN_YAW_90.as_quat(), True)),
                               expected, atol=1e-9)
    with pytest.raises(ValueError, match="speed"):
        URArm("h", speed=2.0, rtde_control=ur.modules["rtde_control"], rtde_receive=ur.modules["rtde_receive"])


def test_ur_arm_reports_failed_motions_and_then_leaves_the_gripper() -> None:
    ur = FakeUR()
    gripper = DryRunGripper()
    arm = URArm("h", gripper, motion_timeout_s=0.05, poll_s=0.001, rtde_control=ur.modules["rtde_control"],
                rtde_receive=ur.modules["rtde_receive"])
    action = KeyframeAction([0.4, 0.0, 0.2], DOWN_YAW_90.as_quat(), False)
    for outcome in ("rejected", "stuck", "missed"):
        ur.outcome = outcome
        assert arm.move(action) == {"stuck": "timeout"}.get(outcome, outcome)
    assert gripper.commands == [] and ("stopL", 4.0) in ur.calls  # the stuck motion was stopped


def test_digital_output_gripper() -> None:
    ur = FakeUR()
    receive = ur.modules["rtde_receive"].RTDEReceiveInterface("h")
    gripper = URDigitalOutputGripper(ur.modules["rtde_io"].RTDEIOInterface("h"), receive, output=3, settle_s=0.0)
    gripper.set_open(False)
    assert ur.calls[-1] == ("setStandardDigitalOut", 3, True) and gripper.opening() == 0.0
    gripper.set_open(True)
    assert ur.calls[-1] == ("setStandardDigitalOut", 3, False) and gripper.opening() == 1.0


class StubPolicy:
    """What ``run_robot`` needs of a policy, predicting one fixed keyframe."""

    last_timings: dict = {}

    def __init__(self, action: KeyframeAction) -> None:
        self.action = action

    def reset(self) -> None:
        pass

    def explain(self, obs, instruction, names) -> SimpleNamespace:  # like abm.policy.PolicyExplanation
        import torch

        return SimpleNamespace(action=self.action, sample={"points": torch.zeros(1, 3)},
                               view_images=np.zeros((5, 10, 4, 4), np.float32), view_mask=None)


def test_a_keyframe_outside_the_limits_never_reaches_movel(tmp_path) -> None:
    ur = FakeUR()
    rs = fake_realsense({"111": (1000, 0)})
    camera = RealSenseCamera(["111"], None, warmup_frames=0, rs_module=rs)
    limits = MotionLimits()
    arm = URArm("h", DryRunGripper(), limits=limits, rtde_control=ur.modules["rtde_control"],
                rtde_receive=ur.modules["rtde_receive"])
    outside = KeyframeAction([0.5, 0.0, 1.5], DOWN_YAW_90.as_quat(), True)  # 1.5 m up: above the box
    with pytest.raises(LimitError, match="outside the workspace box"):
        run_robot(StubPolicy(outside), camera, arm, "pick up the cube", limits, 3, tmp_path / "log")
    with pytest.raises(LimitError):  # the arm checks again when driven directly
        arm.move(outside)
    assert ur.moves() == []
    inside = KeyframeAction([0.5, 0.0, 0.2], DOWN_YAW_90.as_quat(), True)
    records = run_robot(StubPolicy(inside), camera, arm, "pick up the cube", limits, 2, tmp_path / "log2")
    assert [r["status"] for r in records] == ["reached", "reached"] and len(ur.moves()) == 2


# ------------------------------------------------------------------------------------------- the robot YAML
ROBOT_YAML = """
cameras: {kind: realsense, serials: {front: "111"}, calibration: CAL, width: 6, height: 6, warmup_frames: 0}
arm:
  kind: ur
  host: 10.0.0.2
  speed: 0.05
  tcp_offset: [0, 0, 0.2, 0, 0, 0]
  gripper: {kind: digital-output, output: 1, settle_s: 0}
limits: {workspace_lower: [-2, -2, -2], workspace_upper: [2, 2, 2], max_step_m: 5, max_tilt_deg: 180}
"""


@pytest.fixture()
def robot_yaml(tmp_path, monkeypatch):
    """A RealSense + UR robot YAML, with the fake SDKs installed as the real module names."""
    ur, rs = FakeUR(), fake_realsense({"111": (800, 50)})
    for name, module in {**ur.modules, "pyrealsense2": rs}.items():
        monkeypatch.setitem(sys.modules, name, module)
    above = _pose([0.5, 0.0, 1.0], Rotation.from_euler("x", 180, degrees=True))  # looking down from 1 m
    save_calibration(tmp_path / "cal.yaml", {"front": {"intrinsics": np.eye(3), "extrinsics": above}})
    path = tmp_path / "robot.yaml"
    path.write_text(ROBOT_YAML.replace("CAL", str(tmp_path / "cal.yaml")))
    return path, ur, rs


def test_robot_yaml_builds_realsense_and_ur(robot_yaml) -> None:
    path, ur, _ = robot_yaml
    config = RobotConfig.load(path)
    camera, arm = config.build()
    assert isinstance(camera, RealSenseCamera) and isinstance(arm, URArm)
    assert isinstance(arm.gripper, URDigitalOutputGripper) and arm.gripper.output == 1
    assert arm.limits == config.limits and arm.speed == 0.05 and ur.controls == 1
    np.testing.assert_allclose(arm.tcp[:3, 3], [0.0, 0.0, 0.2])
    # a dry run only reads the arm: no control interface, a DryRunArm starting at the arm's TCP pose
    camera, arm = config.build(dry_run=True)
    assert isinstance(arm, DryRunArm) and ur.controls == 1
    np.testing.assert_allclose(arm.state()[0][:3, 3], [0.5, 0.0, 0.1], atol=1e-9)  # 20 cm below the flange
    bad = dataclasses.replace(config, arm={"kind": "ur", "host": "h", "gripper": {"kind": "vacuum"}})
    with pytest.raises(ValueError, match="unknown gripper kind 'vacuum'"):
        bad.build()
    with pytest.raises(ValueError, match="unknown ur options"):
        dataclasses.replace(config, arm={"kind": "ur", "host": "h", "sped": 1}).build()


def test_abm_run_on_realsense_and_ur(robot_yaml, tmp_path, capsys) -> None:
    from abm.cli import main as cli_main
    from abm.train import TrainConfig, train
    from abm.train.synthetic import synthetic_episodes

    path, ur, _ = robot_yaml
    train(TrainConfig(method="rvt", out=tmp_path / "run", steps=1, batch=2, policy=TINY_POLICY,
                      progress=False), synthetic_episodes(2, 32))  # rvt: no grounding, so no segmentation needed
    common = ["run", "--robot", str(path), "--run", str(tmp_path / "run"), "--instruction",
              "put the red block on the target", "--steps", "2"]
    assert cli_main([*common, "--dry-run", "--log", str(tmp_path / "dry")]) == 0
    assert ur.moves() == [] and ur.controls == 0  # nothing moved, nothing took control
    assert cli_main([*common, "--log", str(tmp_path / "live")]) == 0
    statuses = [json.loads(line)["status"] for line in (tmp_path / "live/steps.jsonl").read_text().splitlines()]
    assert statuses == ["reached", "reached"] and len(ur.moves()) == 2
    assert "abm run: 2 keyframes" in capsys.readouterr().out


# --------------------------------------------------------------------------------------- real demonstrations
class HandGuided:
    """Camera and arm of a robot moved by hand through recorded observations (``order``: which observation each
    capture sees); frames lack segmentation and object names, as a real camera's do."""

    def __init__(self, observations, order) -> None:
        self.observations, self.order, self.k, self.object_names = observations, list(order), 0, {}

    def read(self):
        obs = self.observations[self.order[self.k]]
        return {n: dataclasses.replace(f, segmentation=None) for n, f in obs.cameras.items()}

    def state(self):
        obs = self.observations[self.order[self.k]]
        self.k += 1
        return obs.gripper_pose, obs.gripper_open


@pytest.fixture(scope="module")
def real_demo(tmp_path_factory, expert_episode):
    """A pick_block expert episode replayed as if demonstrated by hand, stored with record_demonstration."""
    from abm.robot.demonstrations import record_demonstration
    episode = expert_episode("pick_block", "seen", 0, 48)
    folder = tmp_path_factory.mktemp("demo")
    observations = [obs for obs, _ in episode.steps]
    record_observations(observations, folder / "rec", episode.object_names, episode.instruction)
    n = len(observations)
    commands = ["", "", "u", "", "x"] + [""] * (n - 2) + ["q"]  # one keyframe dropped again, one typo
    robot = HandGuided(observations, [0, 1, *range(1, n)])
    lines: list[str] = []
    path = record_demonstration(robot, robot, episode.instruction, folder / "data", commands=iter(commands),
                                echo=lines.append)
    return path, folder, observations, episode, lines


def test_recorded_demonstration_round_trips_through_the_episode_store(real_demo) -> None:
    from abm.data.episode_store import EpisodeStore
    from abm.geometry.rotations import symmetric_angle_deg

    path, folder, observations, episode, lines = real_demo
    out = folder / "data"
    assert path == out / "real/seen/episode_000000.h5"
    assert any("dropped keyframe 1" in line for line in lines) and any("unknown command" in line for line in lines)
    store = EpisodeStore(out)
    assert len(store) == 1 and store.episodes[0].task == "real"
    loaded = store.load(0)
    assert len(loaded) == len(observations) - 1 and loaded.object_names == {} and loaded.target_names == []
    assert loaded.metadata["source"] == "real-robot" and loaded.instruction == episode.instruction
    for k, (obs, action) in enumerate(loaded.steps):
        assert obs.step == k and obs.cameras["front"].rgb.shape == (48, 48, 3)
        assert obs.cameras["front"].depth.shape == (48, 48) and obs.cameras["front"].segmentation is None
        np.testing.assert_allclose(obs.gripper_pose, observations[k].gripper_pose)
        reached = observations[k + 1]
        np.testing.assert_allclose(action.position, reached.gripper_pose[:3, 3])
        quat = Rotation.from_matrix(reached.gripper_pose[:3, :3]).as_quat()
        assert symmetric_angle_deg(action.quaternion, quat, 2) < 1e-4
        assert action.gripper_open == (reached.gripper_open > 0.5)
    # the images are the recorded ones
    np.testing.assert_array_equal(loaded.steps[1][0].cameras["front"].rgb, observations[1].cameras["front"].rgb)


def test_real_demonstrations_train_and_the_oracle_refuses_them(real_demo, tmp_path) -> None:
    from abm.grounding.config import ClipGrounderConfig
    from abm.robot.demonstrations import check_instruction
    from abm.train import TrainConfig, train

    out = real_demo[1] / "data"
    # abm with the CLIP grounder (a random tiny CLIP here): grounding cache filled, then two steps
    summary = train(TrainConfig(method="abm", data=out, out=tmp_path / "clip", steps=2, batch=2,
                                grounder=ClipGrounderConfig(model="tiny"), language="hash",
                                policy=TINY_POLICY, progress=False))
    assert summary["steps"] == 2 and np.isfinite(summary["final_loss"]["total"])
    with pytest.raises(ValueError, match="oracle grounder needs"):  # no segmentation, no object names
        train(TrainConfig(method="abm", data=out, out=tmp_path / "abm", steps=1, batch=2, policy=TINY_POLICY,
                          progress=False))
    with pytest.raises(ValueError, match="matches no skill template"):
        check_instruction("dance a little")


def test_record_demonstration_command_line(real_demo, tmp_path, monkeypatch) -> None:
    from abm.data.episode_store import load_episode
    from abm.robot.demonstrations import main

    _, _, observations, episode, _ = real_demo
    robot = tmp_path / "robot.yaml"
    robot.write_text(f"cameras: {{kind: replay, path: {real_demo[1] / 'rec'}}}\narm: {{kind: dry-run}}\n")
    monkeypatch.setattr("sys.stdin", io.StringIO("\nc\n\nq\n"))
    assert main(["--robot", str(robot), "--instruction", episode.instruction, "--out", str(tmp_path / "d"),
                 "--task", "pick_block"]) == 0
    loaded = load_episode(tmp_path / "d/pick_block/seen/episode_000000.h5")
    assert len(loaded) == 1 and loaded.steps[0][1].gripper_open is False  # closed with "c" before the capture
