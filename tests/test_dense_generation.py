"""``abm data generate --dense`` in the simulator: the trajectory at a fixed control rate contains every
keyframe observation, and survives a LeRobot export / import."""

import json

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator("h5py")

from abm.cli import main  # noqa: E402
from abm.data.episode_store import find_episode_files, load_episode  # noqa: E402


def test_dense_generation_and_lerobot_round_trip(tmp_path, capsys):
    pytest.importorskip("av")
    pytest.importorskip("pyarrow")
    data = tmp_path / "data"
    args = ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--out", str(data),
            "--resolution", "32", "--dense", "--dense-fps", "10"]
    assert main(args) == 0
    [path] = find_episode_files(data)
    ep = load_episode(path)
    traj = ep.trajectory
    assert traj is not None and traj.fps == 10.0 and ep.metadata["dense_fps"] == 10.0
    assert len(traj) > 3 * len(ep.steps) and len(traj.keyframe_frames) == len(ep.steps)
    assert traj.keyframe_frames[0] == 0
    for (obs, _), f in zip(ep.steps, traj.keyframe_frames, strict=True):  # keyframes are dense frames
        assert np.array_equal(obs.cameras["front"].rgb, traj.observations[f].cameras["front"].rgb)
        assert np.array_equal(obs.gripper_pose, traj.observations[f].gripper_pose)
    # the gripper command closes somewhere and the arm moves between ticks
    assert traj.joint_actions[:, 7].min() == 0.0 and traj.joint_actions[:, 7].max() == 1.0
    assert np.abs(np.diff(traj.joint_positions[:, :7], axis=0)).max() > 1e-3
    assert np.all(np.sum(traj.ee_actions[1:, 3:7] * traj.ee_actions[:-1, 3:7], axis=1) > 0)  # sign-continuous
    # resuming without --dense into the dense folder is refused
    assert main(args[:-3] + ["--episodes", "2"]) == 2
    assert "keyframes only" in capsys.readouterr().err

    ds = tmp_path / "ds"
    assert main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    info = json.loads((ds / "meta" / "info.json").read_text())
    assert info["fps"] == 10.0 and info["total_frames"] == len(traj)
    assert main(["data", "import", "--format", "lerobot", str(ds), "--out", str(tmp_path / "back")]) == 0
    again = load_episode(tmp_path / "back" / path.relative_to(data))
    assert np.array_equal(again.trajectory.keyframe_frames, traj.keyframe_frames)
    for (o1, a1), (o2, a2) in zip(ep.steps, again.steps, strict=True):
        assert np.array_equal(a1.position, a2.position) and a1.kind == a2.kind
        assert np.array_equal(o1.cameras["front"].depth, o2.cameras["front"].depth)
    assert np.allclose(again.trajectory.joint_actions, traj.joint_actions, atol=1e-5)


def test_a_control_rate_off_the_physics_clock_is_refused(tmp_path, capsys):
    args = ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--out", str(tmp_path),
            "--dense", "--dense-fps"]
    for fps in ("3", "1000"):
        assert main([*args, fps]) == 2
        assert "whole number of physics steps of 2 ms" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:  # not a rate at all: refused when the options are parsed
        main([*args, "0"])
    assert exit_info.value.code == 2 and "expected a finite number > 0" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())  # refused before anything ran
