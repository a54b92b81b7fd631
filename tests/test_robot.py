"""The deployment loop (abm run): recorded camera, dry-run and MuJoCo arms, motion limits, logs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from abm.cli import main as cli_main
from abm.errors import ConfigError
from abm.robot import DryRunArm, LimitError, MotionLimits, NoTargetError, ReplayCamera, record_observations, run_robot
from abm.types import KeyframeAction

# an untrained policy points anywhere in its 1 m workspace cube: limits that allow all of it
OPEN = MotionLimits(workspace_lower=(0.0, -0.5, -0.15), workspace_upper=(1.0, 0.5, 0.85), max_step_m=2.0,
                    max_tilt_deg=180.0)
OPEN_YAML = ("limits: {workspace_lower: [0, -0.5, -0.15], workspace_upper: [1, 0.5, 0.85], max_step_m: 2.0, "
             "max_tilt_deg: 180}\n")


@pytest.fixture(scope="module")
def recording(tmp_path_factory, expert_episode):
    """A pick_block expert episode recorded from the simulator (48-pixel cameras)."""
    episode = expert_episode("pick_block", "seen", 0, 48)
    folder = tmp_path_factory.mktemp("rec")
    record_observations([obs for obs, _ in episode.steps], folder, episode.object_names, episode.instruction)
    return folder, episode


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, shared_tiny_run):
    """A trained tiny abm run (the session's one, copied for this module)."""
    run = tmp_path_factory.mktemp("run") / "run"
    shutil.copytree(shared_tiny_run, run)
    return run


def test_replay_camera_gives_back_the_recorded_frames(recording) -> None:
    folder, episode = recording
    camera = ReplayCamera(folder)
    assert camera.steps == len(episode.steps) and camera.object_names == episode.object_names
    for obs, _ in episode.steps:
        frames = camera.read()
        for name, frame in obs.cameras.items():
            np.testing.assert_array_equal(frames[name].rgb, frame.rgb)
            np.testing.assert_array_equal(frames[name].segmentation, frame.segmentation)
    camera.read()  # past the end: the last frame again
    pose, opening = camera.recorded_gripper()
    np.testing.assert_allclose(pose, episode.steps[0][0].gripper_pose)
    with pytest.raises(ConfigError, match="meta.json"):
        ReplayCamera(folder / "nothing")


def test_limits_refuse_with_the_reason() -> None:
    limits = MotionLimits(workspace_lower=(0.2, -0.3, 0.0), workspace_upper=(0.8, 0.3, 0.5), max_step_m=0.3,
                          max_tilt_deg=30)
    here = np.eye(4)
    here[:3, 3] = [0.5, 0.0, 0.2]
    down = np.array([1.0, 0.0, 0.0, 0.0])  # x, y, z, w: 180 deg about x, gripper pointing down
    limits.check(here, KeyframeAction([0.55, 0.05, 0.1], down, True))
    with pytest.raises(LimitError, match="outside the workspace box"):
        limits.check(here, KeyframeAction([0.55, 0.5, 0.1], down, True))
    with pytest.raises(LimitError, match="exceeds max_step_m"):
        limits.check(here, KeyframeAction([0.79, 0.25, 0.45], down, True))
    with pytest.raises(LimitError, match="tilted 90 deg"):
        limits.check(here, KeyframeAction([0.55, 0.05, 0.1], [0.0, 0.7071068, 0.0, 0.7071068], True))


def test_run_on_a_recording_with_a_dry_run_arm(recording, checkpoint, tmp_path) -> None:
    from abm.policy import KeyframePolicy

    folder, episode = recording
    policy = KeyframePolicy.from_checkpoint(checkpoint)
    camera = ReplayCamera(folder)
    arm = DryRunArm(*camera.recorded_gripper())
    records = run_robot(policy, camera, arm, episode.instruction, OPEN, 3, tmp_path / "log")
    assert len(records) == len(arm.commands) == 3
    lines = [json.loads(line) for line in (tmp_path / "log/steps.jsonl").read_text().splitlines()]
    assert [r["status"] for r in lines] == ["dry-run"] * 3
    step = np.load(tmp_path / "log/step_000.npz")
    assert step["views"].shape == (5, 3, 32, 32) and step["mask"].shape == (5, 32, 32)
    assert "camera/front" in step.files
    # a keyframe outside the limits stops the loop before the arm moves
    arm = DryRunArm(*camera.recorded_gripper())
    with pytest.raises(LimitError):
        run_robot(policy, ReplayCamera(folder), arm, episode.instruction,
                  MotionLimits(workspace_lower=(0.0, 0.0, 0.9), workspace_upper=(0.1, 0.1, 1.0)), 3, tmp_path / "l2")
    assert arm.commands == []
    refused = json.loads((tmp_path / "l2/steps.jsonl").read_text().splitlines()[0])
    assert refused["status"] == "refused" and "outside the workspace box" in refused["reason"]


def test_abm_run_cli_with_sim_and_dry_run(recording, checkpoint, tmp_path, capsys) -> None:
    folder, episode = recording
    replay = tmp_path / "replay.yaml"
    replay.write_text(f"cameras: {{kind: replay, path: {folder}}}\narm: {{kind: dry-run}}\n" + OPEN_YAML)
    assert cli_main(["run", "--robot", str(replay), "--run", str(checkpoint), "--steps", "2",
                     "--log", str(tmp_path / "a")]) == 0
    out = capsys.readouterr()
    assert "abm run: 2 keyframes" in out.out
    assert out.err.count(f"abm run: {episode.instruction!r} (target: ") == 1  # the instruction, logged once
    first = json.loads((tmp_path / "a/steps.jsonl").read_text().splitlines()[0])
    assert first["instruction"] == episode.instruction
    sim = tmp_path / "sim.yaml"
    sim.write_text("arm: {kind: sim, task: pick_block, split: seen, seed: 1, resolution: 48}\n" + OPEN_YAML)
    assert cli_main(["run", "--robot", str(sim), "--run", str(checkpoint), "--steps", "2",
                     "--log", str(tmp_path / "b")]) == 0
    statuses = [json.loads(line)["status"] for line in (tmp_path / "b/steps.jsonl").read_text().splitlines()]
    assert len(statuses) == 2 and set(statuses) <= {"reached", "unreachable", "blocked", "collided"}
    tight = tmp_path / "tight.yaml"
    tight.write_text(f"cameras: {{kind: replay, path: {folder}}}\n"
                     "limits: {workspace_lower: [0, 0, 0.9], workspace_upper: [0.1, 0.1, 1.0]}\n")
    assert cli_main(["run", "--robot", str(tight), "--run", str(checkpoint), "--log", str(tmp_path / "c")]) == 2
    assert "refused before moving" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("limbs: {}\n")
    assert cli_main(["run", "--robot", str(bad), "--run", str(checkpoint)]) == 2
    assert "unknown keys ['limbs']" in capsys.readouterr().err
    assert cli_main(["run", "--robot", str(replay), "--run", str(checkpoint), "--clip-model", "tiny"]) == 2
    assert "--clip-model applies to --grounder clip or tracking" in capsys.readouterr().err


def test_run_refuses_to_move_when_grounding_finds_no_target(recording, checkpoint, tmp_path, capsys) -> None:
    """An instruction whose object is not in the scene: an empty mask, so nothing moves, on both arms."""
    from abm.policy import KeyframePolicy

    folder, episode = recording
    held = sorted(set(episode.object_names.values()))
    policy = KeyframePolicy.from_checkpoint(checkpoint)
    camera = ReplayCamera(folder)
    arm = DryRunArm(*camera.recorded_gripper())
    with pytest.raises(NoTargetError, match=f"no target to act on for 'put the ketchup on the target': .*holds: "
                                            f"{held[0]}"):
        run_robot(policy, camera, arm, "put the ketchup on the target", OPEN, 2, tmp_path / "log")
    assert arm.commands == []
    refused = json.loads((tmp_path / "log/steps.jsonl").read_text())
    assert refused["status"] == "refused" and "--allow-no-target" in refused["reason"]
    # the same instruction with a target in the scene moves
    assert len(run_robot(policy, ReplayCamera(folder), arm, episode.instruction, OPEN, 1, tmp_path / "ok")) == 1
    # the command, dry run and MuJoCo arm: exit 2 with one line, unless --allow-no-target
    replay = tmp_path / "replay.yaml"
    replay.write_text(f"cameras: {{kind: replay, path: {folder}}}\narm: {{kind: dry-run}}\n" + OPEN_YAML)
    sim = tmp_path / "sim.yaml"
    sim.write_text("arm: {kind: sim, task: pick_block, split: seen, seed: 1, resolution: 48}\n" + OPEN_YAML)
    for robot in (replay, sim):
        log_dir = tmp_path / robot.stem
        base = ["run", "--robot", str(robot), "--run", str(checkpoint), "--steps", "1", "--log", str(log_dir),
                "--instruction", "put the ketchup on the target"]
        assert cli_main(base) == 2
        errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("abm: error: ")]
        assert len(errors) == 1 and "refused before moving: no target to act on" in errors[0]
        assert "'ketchup' is not in the scene" in errors[0]
        assert "the scene holds: " in errors[0] and "block" in errors[0]
        assert cli_main([*base, "--allow-no-target"]) == 0
        status = json.loads((log_dir / "steps.jsonl").read_text().splitlines()[0])["status"]
        assert status in {"dry-run", "reached", "unreachable", "blocked", "collided"}


def _rotation(rng, max_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rng.normal(size=3) * np.radians(max_deg) / 2).as_matrix()


def test_hand_eye_calibration_recovers_a_known_camera(tmp_path, capsys) -> None:
    """Synthetic board images from known poses: the camera-to-base transform within 5 mm and 1 degree."""
    from abm.robot.calibration import BoardSpec, load_calibration, render_board_image
    from abm.types import CameraFrame, Observation

    rng = np.random.default_rng(0)
    spec = BoardSpec()
    k = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    base_cam = np.eye(4)  # the truth: a camera 1.2 m in front of the robot, looking back at it
    base_cam[:3, :3] = _rotation(rng, 10) @ np.array([[0, 0, -1], [-1, 0, 0], [0, 1, 0]]).T.T
    base_cam[:3, 3] = [1.2, 0.1, 0.4]
    grip_board = np.eye(4)  # the board on the gripper, at an offset the calibration does not know
    grip_board[:3, :3] = _rotation(rng, 20)
    grip_board[:3, 3] = [0.02, -0.03, 0.08]
    observations = []
    for _ in range(12):
        cam_board = np.eye(4)  # the board facing the camera, tilted, near the optical axis
        cam_board[:3, :3] = _rotation(rng, 40)
        cam_board[:3, 3] = [-0.1 + rng.normal(0, 0.03), -0.14 + rng.normal(0, 0.03), 0.6 + rng.normal(0, 0.05)]
        base_grip = base_cam @ cam_board @ np.linalg.inv(grip_board)
        image = render_board_image(spec, k, cam_board)
        frame = CameraFrame(rgb=image, depth=np.ones(image.shape[:2], np.float32), intrinsics=k, extrinsics=np.eye(4))
        observations.append(Observation({"front": frame}, 0.0, base_grip))
    record_observations(observations, tmp_path / "rec")
    out = tmp_path / "calibration.yaml"
    assert cli_main(["calibrate", "--recording", str(tmp_path / "rec"), "--camera", "front", "--out", str(out)]) == 0
    assert "from 12 views" in capsys.readouterr().out
    got = load_calibration(out)["front"]["extrinsics"]
    position_mm = 1000 * np.linalg.norm(got[:3, 3] - base_cam[:3, 3])
    angle_deg = np.degrees(np.arccos(np.clip((np.trace(got[:3, :3].T @ base_cam[:3, :3]) - 1) / 2, -1, 1)))
    assert position_mm < 5 and angle_deg < 1, (position_mm, angle_deg)
    assert cli_main(["calibrate", "--recording", str(tmp_path / "rec"), "--camera", "top", "--out", str(out)]) == 2
    assert "not in the recording" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:  # --board is checked when the command line is parsed
        cli_main(["calibrate", "--recording", str(tmp_path / "rec"), "--camera", "front", "--out", str(out),
                  "--board", "5x7"])
    assert exit_info.value.code == 2
    assert "argument --board: expected XxY:SQUARE_M:MARKER_M:DICTIONARY" in capsys.readouterr().err


def test_shipped_robot_examples_run_dry(checkpoint, tmp_path, capsys) -> None:
    """examples/robot_sim.yaml (MuJoCo arm + simulated cameras) and examples/robot_replay.yaml on a recording
    made by `abm record` both run with --dry-run: one logged keyframe, the arm never commanded."""
    from pathlib import Path

    from abm.robot import RobotConfig

    examples = Path(__file__).resolve().parents[1] / "examples"
    sim = RobotConfig.load(examples / "robot_sim.yaml")
    assert sim.cameras == {"kind": "sim"} and sim.arm["kind"] == "sim"
    recording = tmp_path / "rec"
    assert cli_main(["record", "--task", "pick_block", "--seed", "0", "--resolution", "32",
                     "--out", str(recording)]) == 0
    assert f"-> {recording}" in capsys.readouterr().out
    replay = tmp_path / "replay.yaml"
    replay.write_text((examples / "robot_replay.yaml").read_text().replace("recordings/demo", str(recording)))
    for name, robot in (("sim", examples / "robot_sim.yaml"), ("replay", replay)):
        code = cli_main(["run", "--robot", str(robot), "--run", str(checkpoint), "--dry-run", "--steps", "1",
                         "--log", str(tmp_path / name)])
        records = [json.loads(line) for line in (tmp_path / name / "steps.jsonl").read_text().splitlines()]
        # an untrained policy may point outside the example's limits: then the run stops before any motion
        assert (code, records[0]["status"]) in ((0, "dry-run"), (2, "refused")), (name, code, records)
        assert "block" in records[0]["instruction"]  # the scene's (or recording's) pick_block instruction
