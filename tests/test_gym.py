"""abm.gym (issue 40 item 5): every task and split as a registered gymnasium environment that passes gymnasium's
env checker, reproduces a scene from its seed, and rewards the scripted expert's keyframes stepped through it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason="the gym extra (pip install 'abm[gym]')")
pytest.importorskip("mujoco", reason="the sim extra")

import abm.gym  # noqa: E402  (registers the environments)
from abm.gym import ENV_IDS, env_id, from_action, to_action, to_observation  # noqa: E402
from abm.sim.splits import load_splits  # noqa: E402
from abm.types import KeyframeAction  # noqa: E402

RES = 24


@pytest.fixture(scope="module")
def env():
    e = gymnasium.make("abm/pick_block-seen-v0", resolution=RES)
    yield e
    e.close()


def test_every_task_and_split_is_registered() -> None:
    wanted = {env_id(t, s) for t, splits in load_splits(None).tasks.items() for s in splits}
    assert set(ENV_IDS) == wanted and all(i.startswith("abm/") for i in ENV_IDS)
    assert {"abm/pick_block-seen-v0", "abm/put_in_container-compositional-v0"} <= set(gymnasium.registry)
    assert gymnasium.spec("abm/close_jar-unseen-v0").kwargs == {"task": "close_jar", "split": "unseen"}
    assert abm.gym.register_envs() == ENV_IDS  # importing again registers nothing new
    with pytest.raises(ValueError, match="no split"):
        gymnasium.make("abm/pick_block-seen-v0", split="compositional")


@pytest.mark.slow
def test_env_checker_passes() -> None:
    from gymnasium.utils.env_checker import check_env

    e = gymnasium.make("abm/pick_block-seen-v0", resolution=RES)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*symmetric and normalized.*")  # metres, not [-1, 1]
        check_env(e.unwrapped)
    e.close()


def test_a_seed_gives_the_same_scene(env) -> None:
    obs, info = env.reset(seed=3)
    other = gymnasium.make("abm/pick_block-seen-v0", resolution=RES)
    again, info_again = other.reset(seed=3)
    other.close()
    for name, cam in obs["cameras"].items():
        np.testing.assert_array_equal(cam["rgb"], again["cameras"][name]["rgb"])
        np.testing.assert_array_equal(cam["segmentation"], again["cameras"][name]["segmentation"])
    assert obs["instruction"] == again["instruction"] and info["object_names"] == info_again["object_names"]
    assert info["scene_seed"] == 3 and obs in env.observation_space
    from abm.sim.env import make_env

    assert obs["instruction"] == make_env("pick_block", "seen", 3).instruction  # the benchmark's scene of seed 3
    moved, _ = env.reset(seed=4)
    assert not np.array_equal(moved["cameras"]["front"]["rgb"], obs["cameras"]["front"]["rgb"])
    np.testing.assert_array_equal(env.reset(seed=3)[0]["cameras"]["front"]["rgb"], obs["cameras"]["front"]["rgb"])


def test_the_expert_succeeds_through_step(env) -> None:
    obs, info = env.reset(seed=0)
    rewards, terminated, truncated = [], False, False
    for keyframe in env.unwrapped.expert_actions():
        obs, reward, terminated, truncated, info = env.step(from_action(keyframe))
        rewards.append(reward)
        assert obs in env.observation_space and info["motion"] in {"reached", "blocked", "collided", "unreachable"}
        if terminated or truncated:
            break
    assert terminated and not truncated and info["success"]
    assert rewards[-1] == 1.0 and set(rewards[:-1]) <= {0.0} and len(rewards) >= 3


def test_truncated_after_max_steps_and_conversions(env) -> None:
    short = gymnasium.make("abm/pick_block-seen-v0", resolution=RES, max_steps=1)
    obs, _ = short.reset(seed=0)
    state = to_observation(obs)
    np.testing.assert_array_equal(state.cameras["wrist"].depth, obs["cameras"]["wrist"]["depth"])
    stay = KeyframeAction(state.gripper_pose[:3, 3], [1.0, 0.0, 0.0, 0.0], True)
    action = from_action(stay)
    assert action in short.action_space and to_action(action).gripper_open
    _, reward, terminated, truncated, info = short.step(stay)  # a KeyframeAction is accepted too
    assert (reward, terminated, truncated, info["step"]) == (0.0, False, True, 1)
    short.close()
    short.close()  # twice is fine
    zero = dict(action, quaternion=np.zeros(4))
    np.testing.assert_allclose(to_action(zero).quaternion, [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="lacks"):
        to_action({"position": np.zeros(3)})


@pytest.mark.slow
def test_the_zoo_example_runs_an_episode() -> None:
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, str(root / "examples" / "gym_zoo_policy.py"), "--resolution", "64",
                           "--max-steps", "2"], capture_output=True, text=True, env=env, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "abm/pick_block-seen-v0 seed 0" in done.stdout and "step 1: position" in done.stdout
    assert "keyframes, return" in done.stdout
