"""ABM-Bench tasks: experts succeed, success is false at the start, splits, env API, data CLI."""

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator("h5py")

from abm.sim.assets import libero_available  # noqa: E402
from abm.sim.env import make_env, run_expert  # noqa: E402
from abm.sim.splits import SplitFileError, load_splits  # noqa: E402
from abm.sim.tasks import TASKS, get_task  # noqa: E402

needs_libero = pytest.mark.skipif(not libero_available(), reason="LIBERO asset wheels not installed")

CASES = [
    ("pick_block", "seen", 0),
    ("pick_block", "unseen", 1),
    pytest.param("place_food", "seen", 0, marks=needs_libero),
    pytest.param("place_food", "unseen", 1, marks=needs_libero),
    pytest.param("place_wine", "seen", 0, marks=needs_libero),
    pytest.param("place_wine", "unseen", 1, marks=needs_libero),
]


def test_registry_has_the_three_tasks():
    assert {"place_food", "pick_block", "place_wine"} <= set(TASKS)
    with pytest.raises(KeyError, match="unknown task"):
        get_task("fly_to_moon")


@pytest.mark.parametrize(("task", "split", "seed"), CASES)
def test_expert_succeeds_and_initial_state_is_not_success(task, split, seed):
    with make_env(task, split, seed, resolution=32) as env:
        env.reset()
        assert not env.success()
        episode = run_expert(env, record=False)
        assert episode.success, episode.metadata["motions"]
        assert all(m == "reached" for m in episode.metadata["motions"])
        assert env.target_names[0] in env.instruction


def test_sampling_is_seeded_and_targets_follow_the_split():
    task = get_task("pick_block")
    a, b = task.sample(7, "seen"), task.sample(7, "seen")
    assert [(o.name, o.x, o.y) for o in a.scene.objects] == [(o.name, o.x, o.y) for o in b.scene.objects]
    seen = set(load_splits().objects("pick_block", "seen"))
    targets = {task.sample(s, "unseen").target_names[0] for s in range(20)}
    assert targets and not targets & seen
    assert all(o.name in seen for o in a.scene.objects if o.name != "target")


def test_env_step_records_observation_and_motion():
    with make_env("pick_block", "seen", 3, resolution=32) as env:
        obs = env.reset()
        assert set(obs.cameras) == {"front", "left_shoulder", "right_shoulder", "wrist"}
        action = next(iter(env.expert_actions()))
        obs, success, info = env.step(action)
        assert not success and info["motion"].ok and not info["done"] and info["step"] == 1
        assert obs.step == 1


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("version: 1\ntasks: [1, 2", r"not a valid split file \(YAML error"),
        ("version: 2\ntasks: {}\n", "'version' must be 1"),
        ("version: 1\ntasks:\n  pick_block:\n    seen: [red block, gold block]\n", "unknown objects.*gold block"),
        ("version: 1\ntasks:\n  juggle:\n    seen: [red block]\n", "unknown task 'juggle'"),
        ("version: 1\ntasks:\n  pick_block:\n    seen: [ketchup]\n", "not of the categories"),
        ("version: 1\ntasks:\n  pick_block:\n    easy: [red block]\n", "unknown split 'easy'"),
        ("version: 1\ntasks:\n  pick_block:\n    seen: []\n", "non-empty list"),
    ],
)
def test_bad_split_file_gives_clear_error(tmp_path, content, match):
    path = tmp_path / "splits.yaml"
    path.write_text(content)
    with pytest.raises(SplitFileError, match=match) as info:
        load_splits(path)
    assert str(path) in str(info.value)


def test_custom_split_file_changes_targets(tmp_path):
    path = tmp_path / "splits.yaml"
    path.write_text("version: 1\ntasks:\n  pick_block:\n    unseen: [red block, green block]\n")
    with make_env("pick_block", "unseen", 0, resolution=32, splits_path=path) as env:
        assert env.target_names[0] in {"red block", "green block"}
    with pytest.raises(SplitFileError, match="no split 'seen'"):
        make_env("pick_block", "seen", 0, splits_path=path)


def test_data_generate_info_and_resume(tmp_path, capsys):
    from abm.cli import main
    from abm.data.episode_store import EpisodeStore

    args = ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1",
            "--out", str(tmp_path), "--resolution", "32", "--seed", "4"]
    assert main(args) == 0
    store = EpisodeStore(tmp_path)
    assert len(store) == 1 and store.episodes[0].success and store.episodes[0].num_keyframes == 6
    obs, action = store.load_step(0, 1)
    assert obs.cameras["front"].rgb.shape == (32, 32, 3) and not action.gripper_open
    assert np.isfinite(obs.gripper_pose).all()
    capsys.readouterr()
    assert main(args) == 0
    assert "0 new, 1 already present" in capsys.readouterr().out
    assert main(["data", "info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "pick_block" in out and "1 episodes" in out
    assert main(["data", "generate", "--task", "nope", "--split", "seen", "--episodes", "1",
                 "--out", str(tmp_path)]) == 2
    (tmp_path / "file").write_text("x")
    capsys.readouterr()
    assert main(["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1",
                 "--out", str(tmp_path / "file")]) == 2
    assert "is a file" in capsys.readouterr().err
    # resuming into the folder with another camera resolution is refused (nothing is simulated)
    other = [a if a != "32" else "48" for a in args[:-2]] + ["--episodes", "2"]
    assert main(other) == 2
    assert "recorded at 32x32 pixels" in capsys.readouterr().err and len(EpisodeStore(tmp_path)) == 1
    assert store.episodes[0].cameras.endswith("@32x32")
