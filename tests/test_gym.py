"""abm.gym (issue 40 item 5): every task and split as a registered gymnasium environment that passes gymnasium's
env checker, reproduces a scene from its seed, and rewards the scripted expert's keyframes stepped through it; every
action outside the action space is refused before the simulator sees it, and episodes end where the spec says."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason="the gym extra (pip install 'abm[gym]')")
pytest.importorskip("mujoco", reason="the sim extra")

import abm.gym  # noqa: E402  (registers the environments)
from abm.gym import ENV_IDS, action_space, check_action, env_id, from_action, to_action, to_observation  # noqa: E402
from abm.sim.env import DEFAULT_MAX_STEPS  # noqa: E402
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
    assert {gymnasium.spec(i).max_episode_steps for i in ENV_IDS} == {DEFAULT_MAX_STEPS} == {25}
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


def test_the_spec_and_the_episodes_agree_on_their_length() -> None:
    made = gymnasium.make("abm/pick_block-seen-v0", resolution=RES, camera_names=("front",))
    assert made.spec is not None and made.spec.max_episode_steps == DEFAULT_MAX_STEPS
    assert made.unwrapped.max_steps is None  # one limit: the TimeLimit of the spec, not a second one inside
    made.close()
    short = gymnasium.make("abm/pick_block-seen-v0", resolution=RES, camera_names=("front",), max_episode_steps=2)
    assert short.spec is not None and short.spec.max_episode_steps == 2
    obs, _ = short.reset(seed=0)
    stay = from_action(KeyframeAction(obs["gripper_pose"][:3, 3], [1.0, 0.0, 0.0, 0.0], True))
    assert short.step(stay)[2:4] == (False, False)
    assert short.step(stay)[2:4] == (False, True)  # truncated after max_episode_steps keyframes
    short.close()


VALID = {"position": np.array([0.5, 0.0, 0.3]), "quaternion": np.array([0.0, 0.0, 0.0, 1.0]), "gripper_open": 1,
         "ignore_collision": 0}
REFUSED = [  # (key, value, what the message says about it)
    ("position", np.array([1e30, 0.0, 0.3]), r"element 0 is 1e\+30, outside \[0, 1\]"),
    ("position", np.array([0.5, 0.0, 0.9]), r"element 2 is 0.9, outside \[-0.15, 0.85\]"),
    ("position", np.array([0.5, -0.6, 0.3]), r"element 1 is -0.6, outside \[-0.5, 0.5\]"),
    ("position", np.array([np.nan, 0.0, 0.3]), "element 0 is nan, not a finite number"),
    ("position", np.array([0.5, np.inf, 0.3]), "element 1 is inf, not a finite number"),
    ("position", None, "expected an array of 3 numbers"),
    ("position", np.zeros(2), r"shape \(2,\), expected \(3,\)"),
    ("position", np.zeros((1, 3)), r"shape \(1, 3\), expected \(3,\)"),
    ("position", 0.5, r"shape \(\), expected \(3,\)"),
    ("position", "0.5 0 0.3", "expected an array of 3 numbers"),
    ("position", ["a", "b", "c"], "expected numbers, got elements of type <U1"),
    ("position", [[0.5], [0.0, 0.3]], "expected an array of 3 numbers"),
    ("position", [0.5, None, 0.3], "expected numbers, got elements of type object"),
    ("position", np.array([0.5, 0.0, 0.3j]), "expected numbers, got elements of type complex128"),
    ("quaternion", np.array([0.0, 0.0, 0.0, 2.0]), r"element 3 is 2, outside \[-1, 1\]"),
    ("quaternion", np.array([0.0, np.nan, 0.0, 1.0]), "element 1 is nan, not a finite number"),
    ("quaternion", np.zeros(3), r"shape \(3,\), expected \(4,\)"),
    ("quaternion", None, "expected an array of 4 numbers"),
    ("gripper_open", 5, "expected 0 or 1"),
    ("gripper_open", -1, "expected 0 or 1"),
    ("gripper_open", np.int64(2), "expected 0 or 1"),
    ("gripper_open", float("nan"), "expected the integer 0 or 1"),
    ("gripper_open", 1.0, "expected the integer 0 or 1"),
    ("gripper_open", None, "expected the integer 0 or 1"),
    ("gripper_open", "1", "expected the integer 0 or 1"),
    ("gripper_open", np.array([1]), "expected the integer 0 or 1"),
    ("ignore_collision", 2, "expected 0 or 1"),
    ("ignore_collision", np.float64(0.0), "expected the integer 0 or 1"),
]


@pytest.mark.parametrize(("key", "value", "says"), REFUSED, ids=[f"{k}={v!r}" for k, v, _ in REFUSED])
def test_an_action_outside_the_space_is_refused_naming_the_space(key: str, value: object, says: str) -> None:
    action = {**VALID, key: value}
    space = action_space()
    assert action not in space  # gymnasium agrees that it is outside
    with pytest.raises(ValueError, match=says) as refused:
        to_action(action)
    message = str(refused.value)
    shown = f"{value!r} ({type(value).__name__})" if not isinstance(value, np.ndarray) else "array("
    assert f"abm.gym action: {key} = {shown}" in message and f"outside the action space's {key} {space[key]}" in message


@pytest.mark.parametrize(("action", "says"), [
    (None, "expected a dict with the keys .* or a KeyframeAction, got None"),
    ([0.5, 0.0, 0.3], "expected a dict with the keys"),
    ({k: v for k, v in VALID.items() if k != "gripper_open"}, r"lacks \['gripper_open'\]"),
    ({**VALID, "speed": 1.0}, r"has unknown keys \['speed'\]"),
    (KeyframeAction(np.array([2.0, 0.0, 0.3]), [0, 0, 0, 1], True), r"position = .* element 0 is 2, outside \[0, 1\]"),
])
def test_a_malformed_action_or_keyframe_is_refused(action: object, says: str) -> None:
    with pytest.raises(ValueError, match=says):
        check_action(action)


@pytest.mark.parametrize("value", [1, True, np.int64(1), np.array(1), np.uint8(1)])
def test_every_form_of_a_flag_in_the_space_is_accepted(value: object) -> None:
    action = {**VALID, "position": [1.0, -0.5, -0.15], "gripper_open": value}  # a corner of the Box: inside
    assert action in action_space()
    assert check_action(action)["gripper_open"] == 1 and to_action(action).gripper_open


def test_the_simulator_never_sees_a_refused_action(env) -> None:
    env.reset(seed=0)
    for key, value, _ in REFUSED:
        with pytest.raises(ValueError, match="outside the action space"):
            env.step({**VALID, key: value})
    with pytest.raises(ValueError, match="outside the action space"):  # no "QP solver daqp failed" from the IK
        env.step(KeyframeAction(np.array([1e30, 0.0, 0.3]), [0, 0, 0, 1], True))
    assert env.unwrapped.env.steps == 0  # nothing was executed


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
