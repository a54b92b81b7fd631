"""robot.yaml, split and template files are checked against their declared schemas when they load: every
bad value is one error naming the file, the key and what is expected; no value can switch a limit off."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from abm.cli import main as cli_main
from abm.robot.limits import LimitError, MotionLimits
from abm.robot.run import RobotConfig
from abm.types import KeyframeAction

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # x, y, z, w: gripper pointing down


@pytest.mark.parametrize("text, message", [
    ("", "the robot file is empty; expected the sections ['arm', 'cameras', 'limits']"),
    ("- cameras\n- arm\n", "expected a mapping with keys ['arm', 'cameras', 'limits'], got ['cameras', 'arm']"),
    ("limits: {workspace_lower: [0, 0, 0\n", "not a valid robot file (YAML error"),
    ("limbs: {}\n", "unknown keys ['limbs'] (expected: ['arm', 'cameras', 'limits'])"),
    ("limits: {max_step_m: .nan}\n", "limits.max_step_m: expected a finite number > 0, got nan"),
    ("limits: {max_step_m: .inf}\n", "limits.max_step_m: expected a finite number > 0, got inf"),
    ("limits: {max_step_m: 0}\n", "limits.max_step_m: expected a finite number > 0, got 0"),
    ("limits: {max_tilt_deg: 270}\n", "limits.max_tilt_deg: expected a finite number > 0 and <= 180, got 270"),
    ("limits: {max_tilt_deg: yes}\n", "limits.max_tilt_deg: expected a finite number > 0 and <= 180, got True"),
    ("limits: {workspace_lower: [0.2, .nan, 0]}\n", "limits.workspace_lower: expected a list of 3 finite numbers"),
    ("limits: {workspace_upper: [1, 1]}\n", "limits.workspace_upper: expected a list of 3 finite numbers, got [1, 1]"),
    ("limits: {workspace_lower: [0.9, 0, 0], workspace_upper: [0.5, 1, 1]}\n",
     "limits: workspace_lower [0.9, 0.0, 0.0] must be below workspace_upper [0.5, 1.0, 1.0] on every axis"),
    ("limits: {max_speed: 1}\n", "limits: unknown keys ['max_speed']"),
    ("limits: [1, 2]\n", "limits: expected a mapping, got [1, 2]"),
    ("arm: {host: 10.0.0.1}\n", "arm: missing required key 'kind' (one of ['dry-run', 'sim', 'ur'])"),
    ("arm: {kind: ur}\n", "arm: missing required keys ['host']"),
    ("arm: {kind: robot}\n", "arm.kind: expected one of ['dry-run', 'sim', 'ur'], got 'robot'"),
    ("arm: {kind: ur, host: h, speed: .nan}\n", "arm.speed: expected a finite number > 0, got nan"),
    ("arm: {kind: ur, host: h, tcp_offset: [0, 0, 0.1]}\n", "arm.tcp_offset: expected a list of 6 finite numbers"),
    ("arm: {kind: sim, task: pick_block, seed: -1}\n",
     "arm.seed: expected a whole number from 0 to 9223372036854775807, got -1"),
    ("arm: {kind: sim, seed: 1}\n", "arm: missing required keys ['task']"),
    ("cameras: {kind: replay}\n", "cameras: missing required keys ['path']"),
    ("cameras: {kind: replay, path: rec, fps: 30}\n", "cameras: unknown keys ['fps'] (expected: ['path'])"),
    ("cameras: {kind: realsense, serials: []}\n", "cameras.serials: expected a non-empty list of names"),
])
def test_bad_robot_files_name_the_key_and_the_expectation(tmp_path, capsys, text, message) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        RobotConfig.load(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value)
    # the command: one abm: error: line, exit code 2, before any checkpoint is read
    assert cli_main(["run", "--robot", str(path), "--run", str(tmp_path / "none"), "--dry-run"]) == 2
    err_text = capsys.readouterr().err
    assert err_text.count("\n") == 1 and err_text.startswith("abm: error: ") and message in err_text


def test_a_good_robot_file_loads_its_values(tmp_path) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text("cameras: {kind: replay, path: rec}\narm: {kind: ur, host: 10.0.0.2, speed: 0.05}\n"
                    "limits: {workspace_lower: [0.3, -0.2, 0], workspace_upper: [0.7, 0.2, 0.4], max_step_m: 0.2}\n")
    config = RobotConfig.load(path)
    assert config.cameras == {"kind": "replay", "path": "rec"}
    assert config.arm == {"kind": "ur", "host": "10.0.0.2", "speed": 0.05}
    assert config.limits == MotionLimits((0.3, -0.2, 0.0), (0.7, 0.2, 0.4), 0.2, 90.0)


@settings(max_examples=60, deadline=None)
@given(key=st.sampled_from(["max_step_m", "max_tilt_deg"]),
       value=st.one_of(st.just(float("nan")), st.just(float("inf")), st.just(-float("inf")),
                       st.floats(max_value=0.0), st.text(max_size=5), st.booleans(), st.none()))
def test_motion_limits_cannot_be_switched_off(key, value) -> None:
    """Any value that would make a check pass vacuously is refused when the limits are made."""
    with pytest.raises(ValueError, match=f"motion limits: {key}: expected a finite number"):
        MotionLimits(**{key: value})


def test_a_nan_target_or_pose_is_refused() -> None:
    limits = MotionLimits()
    here = np.eye(4)
    here[:3, 3] = [0.5, 0.0, 0.2]
    limits.check(here, KeyframeAction([0.5, 0.0, 0.1], DOWN, True))
    action = KeyframeAction([0.5, 0.0, 0.1], DOWN, True)
    action.position = np.array([0.5, float("nan"), 0.1])  # changed after its checks
    with pytest.raises(LimitError, match="not finite"):
        limits.check(here, action)
    lost = here.copy()
    lost[0, 3] = float("nan")
    with pytest.raises(LimitError, match="exceeds max_step_m"):
        limits.check(lost, KeyframeAction([0.5, 0.0, 0.1], DOWN, True))


def test_split_files_refuse_unknown_keys_and_repeated_objects(tmp_path) -> None:
    from abm.sim.splits import SplitFileError, load_splits

    path = tmp_path / "splits.yaml"
    path.write_text("version: 1\ntasks: {pick_block: {seen: [red block]}}\ntask: {}\n")
    with pytest.raises(SplitFileError, match=r"splits.yaml: unknown keys \['task'\]"):
        load_splits(path)
    path.write_text("version: 1\ntasks: {pick_block: {seen: [red block, red block, red block]}}\n")
    with pytest.raises(SplitFileError, match=r"pick_block/seen lists \['red block'\] more than once"):
        load_splits(path)


def test_template_files_refuse_unknown_keys_and_name_the_file(tmp_path) -> None:
    from abm.language.instruction import load_templates

    path = tmp_path / "templates.yaml"
    path.write_text("skills: []\nskils: []\n")
    with pytest.raises(ValueError, match=r"templates.yaml: unknown keys \['skils'\]"):
        load_templates(path)
    path.write_text("skills: [{skill: pick X}]\n")
    with pytest.raises(ValueError, match=r"templates.yaml: templates skills\[0\] needs 'skill' and 'patterns'"):
        load_templates(path)


def test_calibration_files_refuse_non_finite_values(tmp_path) -> None:
    from abm.robot.calibration import load_calibration

    path = tmp_path / "calibration.yaml"
    eye = "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]"
    path.write_text(f"cameras: {{front: {{intrinsics: [[.nan, 0, 1], [0, 1, 1], [0, 0, 1]], extrinsics: {eye}}}}}\n")
    with pytest.raises(ValueError, match="calibration.yaml: camera 'front': .* finite"):
        load_calibration(path)
    path.write_text(f"cameras: {{front: {{intrinsics: [[1, 0, 1], [0, 1, 1], [0, 0, 1]], extrinsics: {eye}, x: 1}}}}\n")
    with pytest.raises(ValueError, match=r"unknown keys \['x'\]"):
        load_calibration(path)
