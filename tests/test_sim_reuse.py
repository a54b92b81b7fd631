"""What a worker keeps between episodes changes nothing an episode sees or does: the thread's GL context (each
scene's renderer draws in it), the IK model compiled once per process, the one-draw depth check made once (the
scenes it keeps for other models: tests/test_scene_cache.py).

An episode after another in the same process renders the same pixels, depth and segmentation as a renderer with
its own GL context, executes the same motions as with a freshly compiled IK model, and an evaluation rollout gives
the same outcome (success, steps, failure, keyframe digest) as the same rollout in a fresh simulator.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator()

import abm.sim.arm_control as arm_control  # noqa: E402
import abm.sim.cameras as cameras  # noqa: E402
from abm.sim.env import make_env  # noqa: E402
from abm.types import Observation  # noqa: E402

ZOO = Path(__file__).resolve().parents[1] / "models"


@pytest.fixture
def fresh_process_state(monkeypatch: pytest.MonkeyPatch) -> Any:
    """A function that makes the simulator behave as in a fresh process: renderers with their own GL context, the
    IK model compiled again, the one-draw check made again."""

    def fresh() -> None:
        from abm.evaluation.scene_cache import forget_scenes

        forget_scenes()
        monkeypatch.setattr(cameras, "scene_renderer", cameras.make_renderer)
        monkeypatch.setattr(cameras, "_ONE_PASS_VERIFIED", False)
        arm_control.ik_model.cache_clear()

    return fresh


def _rollout(task: str, seed: int) -> tuple[list[Observation], list[tuple[str, float]], np.ndarray]:
    """The expert's first two keyframes on a scene at 32 px: the observation before each keyframe and after the
    last, each motion's status and error, and the final simulator state."""
    with make_env(task, "seen", seed, resolution=32) as env:
        env.reset()
        sim = env._require_sim()
        observations, motions = [], []
        for action in itertools.islice(env.expert_actions(), 2):
            observations.append(sim.observe())
            motion = sim.execute(action)
            motions.append((motion.status, motion.position_error))
        observations.append(sim.observe())
        return observations, motions, np.concatenate([sim.data.qpos, sim.data.qvel])


def _same_observations(a: list[Observation], b: list[Observation]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        for name in x.cameras:
            fx, fy = x.cameras[name], y.cameras[name]
            assert np.array_equal(fx.rgb, fy.rgb), name
            assert np.array_equal(fx.depth, fy.depth), name
            assert np.array_equal(fx.segmentation, fy.segmentation), name


def test_a_scene_after_another_renders_and_moves_as_in_a_fresh_process(fresh_process_state) -> None:
    _rollout("place_food", 11)  # the worker's earlier episode: another scene, other objects
    assert cameras._GL_CONTEXTS and cameras._ONE_PASS_VERIFIED
    reused = _rollout("pick_block", 4)
    assert reused[1] and all(status == "reached" for status, _ in reused[1])
    fresh_process_state()
    fresh = _rollout("pick_block", 4)
    _same_observations(reused[0], fresh[0])
    assert reused[1] == fresh[1]
    assert np.array_equal(reused[2], fresh[2])
    assert any(o.cameras["front"].segmentation.max() >= 0 for o in fresh[0])  # the objects are in view


def test_evaluation_rollouts_after_others_give_the_outcomes_of_fresh_ones(fresh_process_state) -> None:
    pytest.importorskip("torch")
    model = ZOO / "abm_oracle_v2.pt"
    if not model.is_file():
        pytest.skip("the committed model zoo is not in this checkout")
    from abm.evaluation.results import eval_seed
    from abm.evaluation.runner import EvalJob, run_job
    from abm.evaluation.settings import EvalSettings

    settings = EvalSettings(max_steps=1)

    def outcome(episode: int) -> tuple[Any, ...]:
        job = EvalJob(str(model), "abm", "place_food", "seen", 0, episode, eval_seed(0, episode),
                      checkpoint=str(model), settings=settings.signature())
        o = run_job(job, settings)
        assert not o.error, o.error
        return o.success, o.steps, o.failure, o.trajectory

    outcome(0)  # the worker's earlier episode
    after_another = outcome(1)
    fresh_process_state()
    assert outcome(1) == after_another and len(after_another[3]) == 16


def test_without_segmentation_the_colour_and_depth_are_the_same_and_no_draw_follows_the_last_keyframe(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from abm.sim.env import run_policy
    from abm.sim.simulation import Simulation

    with make_env("place_food", "seen", 3, resolution=32) as full, \
            make_env("place_food", "seen", 3, resolution=32, segmentation=False) as lean:
        a, b = full.reset(), lean.reset()
        for name, frame in a.cameras.items():
            assert np.array_equal(frame.rgb, b.cameras[name].rgb)
            assert np.array_equal(frame.depth, b.cameras[name].depth)
            assert frame.segmentation is not None and b.cameras[name].segmentation is None
        assert cameras._COLOUR_DEPTH_VERIFIED is True  # the colour draw's depth was compared once and equal

        action = next(iter(lean.expert_actions()))
        draws = []
        observe = Simulation.observe
        monkeypatch.setattr(Simulation, "observe", lambda self: draws.append(1) or observe(self))
        episode = run_policy(lean, lambda obs: action, max_steps=2)
        assert len(episode.steps) == 2 and len(draws) == 2  # the first observation and the one after keyframe 1


def test_only_policies_grounded_by_the_oracle_need_the_segmentation() -> None:
    from types import SimpleNamespace

    from abm.evaluation.policies import needs_segmentation

    def policy(spec: Any) -> Any:
        return SimpleNamespace(grounder_spec=spec)

    assert needs_segmentation(policy({"kind": "oracle"}))
    assert needs_segmentation(policy({"kind": "tracking", "inner": {"kind": "oracle"}}))
    assert needs_segmentation(policy(None))  # a grounder object without a configuration: kept safe
    assert not needs_segmentation(policy({"kind": "clip", "model": "models/benchmark-clip"}))
    assert not needs_segmentation(policy({"kind": "tracking", "inner": {"kind": "clip", "model": "x"}}))


def test_scenes_alive_together_each_render_their_own_pictures(fresh_process_state) -> None:
    """Renderers of several scenes alive in one thread (a gym env caches scenes) each draw into their own buffer."""
    with make_env("pick_block", "seen", 3, resolution=32) as a, make_env("place_food", "seen", 5, resolution=32) as b:
        first_a = a.reset()
        b.reset()
        again_a = a.reset()  # after b's renderer was made and drew
        first_b = b._require_sim().observe()
    fresh_process_state()
    with make_env("place_food", "seen", 5, resolution=32) as fresh:
        fresh.reset()
        reference_b = fresh._require_sim().observe()
    _same_observations([first_a], [again_a])
    _same_observations([first_b], [reference_b])
