"""A scene rolled out again in the same process (another model of the same evaluation) takes over the earlier
build's compiled model and renderer, and the episode is still the one a fresh build gives: the same pixels, depth,
segmentation, motions and final state; the same evaluation outcome; evaluations run every model's rollout of a
scene one after another."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator()

import abm.sim.simulation as simulation  # noqa: E402
from abm.evaluation import scene_cache  # noqa: E402
from abm.evaluation.results import EpisodeOutcome, eval_seed  # noqa: E402
from abm.evaluation.runner import EvalJob, evaluate, scene_groups  # noqa: E402
from abm.evaluation.settings import EvalSettings  # noqa: E402
from abm.sim.env import TaskEnv, make_env  # noqa: E402

ZOO = Path(__file__).resolve().parents[1] / "models"


@pytest.fixture(autouse=True)
def no_kept_scenes() -> Any:
    scene_cache.forget_scenes()
    yield
    scene_cache.forget_scenes()


@pytest.fixture
def compiles(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the scenes compiled (``build_spec`` calls of :class:`abm.sim.simulation.Simulation`)."""
    counted: list[int] = []
    build = simulation.build_spec
    monkeypatch.setattr(simulation, "build_spec", lambda scene: counted.append(1) or build(scene))
    return counted


def _episode(env: TaskEnv, keyframes: int = 2) -> tuple[list[Any], list[tuple[str, float]], np.ndarray]:
    """The expert's first keyframes in ``env``: the observations before each and after the last, each motion's
    status and error, the final simulator state."""
    env.reset()
    sim = env._require_sim()
    observations, motions = [], []
    for action in itertools.islice(env.expert_actions(), keyframes):
        observations.append(sim.observe())
        motion = sim.execute(action)
        motions.append((motion.status, motion.position_error))
    observations.append(sim.observe())
    return observations, motions, np.concatenate([sim.data.qpos, sim.data.qvel, sim.data.ctrl])


def _same(a: tuple[Any, ...], b: tuple[Any, ...]) -> None:
    assert len(a[0]) == len(b[0])
    for x, y in zip(a[0], b[0], strict=True):
        for name in x.cameras:
            fx, fy = x.cameras[name], y.cameras[name]
            assert np.array_equal(fx.rgb, fy.rgb) and np.array_equal(fx.depth, fy.depth), name
            assert np.array_equal(fx.segmentation, fy.segmentation), name
    assert a[1] == b[1]
    assert np.array_equal(a[2], b[2])


def test_a_scene_built_from_an_earlier_build_of_it_steps_and_renders_as_a_fresh_build(compiles) -> None:
    earlier = make_env("pick_block", "seen", 4, resolution=32)
    moved = _episode(earlier, keyframes=3)  # the earlier rollout left the arm and objects elsewhere
    earlier_sim = earlier._require_sim()
    model = earlier_sim.model
    reused_env = make_env("pick_block", "seen", 4, resolution=32, reuse=earlier)
    reused = _episode(reused_env)
    assert reused_env._require_sim().model is model and len(compiles) == 1  # not compiled again
    assert earlier.sim is None and earlier_sim._cameras is None  # handed over, not freed
    with make_env("pick_block", "seen", 4, resolution=32) as fresh_env:
        fresh = _episode(fresh_env)
    assert len(compiles) == 2
    _same(reused, fresh)
    assert reused[1] and all(status == "reached" for status, _ in reused[1])
    assert not np.array_equal(moved[2][:reused[2].size], reused[2])  # the reused scene did start over
    reused_env.close()


def test_another_scene_or_other_cameras_are_built_fresh_and_the_earlier_build_is_closed(compiles) -> None:
    earlier = make_env("pick_block", "seen", 4, resolution=32)
    earlier.reset()
    other_seed = make_env("pick_block", "seen", 5, resolution=32, reuse=earlier)
    other_seed.reset()
    assert len(compiles) == 2 and earlier.sim is None
    larger = make_env("pick_block", "seen", 5, resolution=40, reuse=other_seed)
    larger.reset()
    assert len(compiles) == 3 and other_seed.sim is None
    larger.close()


@pytest.mark.parametrize("first, then", [(True, False), (False, True)])
def test_a_build_serves_rollouts_with_and_without_segmentation_as_fresh_builds(compiles, first: bool,
                                                                                then: bool) -> None:
    earlier = make_env("place_food", "seen", 3, resolution=32, segmentation=first)
    _episode(earlier, keyframes=1)
    reused_env = make_env("place_food", "seen", 3, resolution=32, segmentation=then, reuse=earlier)
    reused = _episode(reused_env)
    assert len(compiles) == 1
    with make_env("place_food", "seen", 3, resolution=32, segmentation=then) as fresh_env:
        fresh = _episode(fresh_env)
    _same(reused, fresh)
    assert all((frame.segmentation is not None) == then for frame in reused[0][0].cameras.values())
    reused_env.close()


@pytest.mark.parametrize("first, then", [(True, False), (False, True), (True, True)])
def test_the_first_observation_is_drawn_once_per_scene_and_is_a_fresh_builds(
        compiles, monkeypatch: pytest.MonkeyPatch, first: bool, then: bool) -> None:
    from abm.sim.cameras import CameraRig

    draws: list[int] = []
    render = CameraRig.render
    monkeypatch.setattr(CameraRig, "render", lambda rig, data: draws.append(1) or render(rig, data))
    earlier = make_env("place_food", "seen", 3, resolution=32, segmentation=first)
    _episode(earlier, keyframes=1)  # the earlier rollout moved the arm, then its environment was reset again
    earlier.reset()
    drawn = len(draws)
    reused_env = make_env("place_food", "seen", 3, resolution=32, segmentation=then, reuse=earlier)
    reused = reused_env.reset()
    assert len(draws) - drawn == (then and not first)  # drawn again only for a segmentation the kept one lacks
    with make_env("place_food", "seen", 3, resolution=32, segmentation=then) as fresh_env:
        fresh = fresh_env.reset()
    assert len(compiles) == 2 and reused.step == fresh.step == 0
    assert np.array_equal(reused.gripper_pose, fresh.gripper_pose) and reused.gripper_open == fresh.gripper_open
    for name, frame in fresh.cameras.items():
        mine = reused.cameras[name]
        assert np.array_equal(mine.rgb, frame.rgb) and np.array_equal(mine.depth, frame.depth), name
        assert np.array_equal(mine.extrinsics, frame.extrinsics), name
        assert (mine.segmentation is None) == (not then) and np.array_equal(mine.segmentation, frame.segmentation)
        mine.rgb[:] = 0  # the caller's own copy: the kept observation is not changed
    again = make_env("place_food", "seen", 3, resolution=32, segmentation=then, reuse=reused_env).reset()
    assert all(np.array_equal(again.cameras[n].rgb, f.rgb) for n, f in fresh.cameras.items())
    scene_cache.forget_scenes()


def test_the_process_keeps_the_last_scene(compiles) -> None:
    for seed in (1, 2):
        with scene_cache.kept_scene("pick_block", "seen", seed, 32, 5) as env:
            env.reset()
    assert scene_cache.kept_count() == scene_cache.KEEP == 1
    with scene_cache.kept_scene("pick_block", "seen", 2, 32, 5, segmentation=False) as env:
        env.reset()
    assert len(compiles) == 2  # seed 2 came from the kept build, without segmentation this time
    with pytest.raises(RuntimeError), scene_cache.kept_scene("pick_block", "seen", 2, 32, 5) as env:
        env.reset()
        raise RuntimeError("a crashed rollout")
    assert scene_cache.kept_count() == 0  # a scene whose block raised is closed, not kept


def test_models_rolled_out_on_one_scene_give_the_outcomes_of_fresh_builds(compiles) -> None:
    pytest.importorskip("torch")
    # with and without segmentation; two grounding with one CLIP (the second from the first's memories)
    models = [ZOO / "abm_oracle_v2.pt", ZOO / "abm_clip_v2.pt", ZOO / "abm_clip_hash_v2.pt"]
    if not all(m.is_file() for m in models):
        pytest.skip("the committed model zoo is not in this checkout")
    from abm.evaluation.policies import forget_policies
    from abm.evaluation.runner import run_job

    settings = EvalSettings(max_steps=2)

    def outcome(model: Path) -> tuple[Any, ...]:
        job = EvalJob(str(model), model.stem, "place_food", "seen", 0, 1, eval_seed(0, 1), checkpoint=str(model),
                      settings=settings.signature())
        o = run_job(job, settings)
        assert not o.error, o.error
        return o.success, o.steps, o.failure, o.trajectory

    shared = [outcome(m) for m in models]
    assert len(compiles) == 1  # one build for both models (the step records' expert runs in it after a rollout)
    fresh = []
    for m in models:
        scene_cache.forget_scenes()
        forget_policies()  # nor any grounding remembered
        fresh.append(outcome(m))
    assert fresh == shared and shared[0] != shared[1]  # different models, each as if alone


def _recording_runner(calls: list[tuple[str, str, int]]) -> Any:
    """A rollout stand-in that records (run, task, seed) and succeeds for run ``a`` only."""

    def runner(job: EvalJob, settings: EvalSettings) -> EpisodeOutcome:
        calls.append((job.run, job.task, job.seed))
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed, job.run == "a",
                              1, 0.0, checkpoint=job.checkpoint, settings=job.settings)

    return runner


def test_an_evaluation_rolls_out_every_models_episode_of_a_scene_together(tmp_path: Path) -> None:
    calls: list[tuple[str, str, int]] = []
    runner = _recording_runner(calls)

    rates = evaluate(["a", "b"], ["pick_block", "place_food"], "seen", tmp_path, episodes=2, repeats=1,
                     labels={"a": "A", "b": "B"}, runner=runner, progress=False)
    seeds = [eval_seed(0, 0), eval_seed(0, 1)]
    assert calls == [(run, task, seed) for task in ("pick_block", "place_food") for seed in seeds for run in "ab"]
    assert {(r.method, r.task): r.mean for r in rates} == {(m, t): 100.0 * (m == "A") for m in "AB"
                                                         for t in ("pick_block", "place_food")}


def test_scene_groups_keep_the_plan_order_within_and_between_scenes() -> None:
    def job(run: str, task: str, episode: int) -> EvalJob:
        return EvalJob(run, run, task, "seen", 0, episode, eval_seed(0, episode))

    jobs = [job(r, t, e) for r in "ab" for t in ("x", "y") for e in (0, 1)]
    groups = scene_groups(jobs)
    assert [[(j.run, j.task, j.episode) for j in g] for g in groups] == [
        [("a", t, e), ("b", t, e)] for t in ("x", "y") for e in (0, 1)]


def test_evaluations_into_their_own_folders_share_the_scenes_and_give_each_ones_own_outcomes(
        tmp_path: Path, compiles) -> None:
    pytest.importorskip("torch")
    models = [ZOO / "abm_oracle_v2.pt", ZOO / "abm_oracle.pt"]
    if not all(m.is_file() for m in models):
        pytest.skip("the committed model zoo is not in this checkout")
    import json

    from abm.evaluation.session import EvalRequest, run_evaluations

    def request(model: Path, out: Path) -> EvalRequest:
        return EvalRequest((model,), tasks=("place_food",), splits=("seen",), episodes=1, repeats=1, workers=1,
                           out=out, settings=EvalSettings(max_steps=1))

    def outcomes(folder: Path) -> list[tuple[Any, ...]]:
        lines = [json.loads(line) for line in (folder / "outcomes.jsonl").read_text().splitlines()]
        return [(o["checkpoint"], o["success"], o["steps"], o["trajectory"]) for o in lines]

    run_evaluations([request(m, tmp_path / "together" / m.stem) for m in models])
    assert len(compiles) == 1  # the one scene, built once for both models
    for m in models:
        scene_cache.forget_scenes()
        run_evaluations([request(m, tmp_path / "alone" / m.stem)])
        assert outcomes(tmp_path / "together" / m.stem) == outcomes(tmp_path / "alone" / m.stem)
        assert (tmp_path / "together" / m.stem / "results.json").is_file()
    assert [Path(c).name for c, *_ in outcomes(tmp_path / "together" / "abm_oracle")] == ["abm_oracle.pt"]


def test_evaluate_together_sends_each_outcome_to_its_own_folder(tmp_path: Path) -> None:
    from abm.evaluation.runner import EvalCell, evaluate_together

    calls: list[tuple[str, str, int]] = []
    runner = _recording_runner(calls)

    cells = [EvalCell([run], ["pick_block"], "seen", tmp_path / run, episodes=2, repeats=1, labels={run: run.upper()})
             for run in "ab"]
    rates = evaluate_together(cells, runner=runner, progress=False)
    assert calls == [(run, "pick_block", eval_seed(0, e)) for e in (0, 1) for run in "ab"]  # scene by scene
    assert [[(r.method, r.mean) for r in cell] for cell in rates] == [[("A", 100.0)], [("B", 0.0)]]
    for run in "ab":
        lines = (tmp_path / run / "outcomes.jsonl").read_text().splitlines()
        assert len(lines) == 2 and all(f'"method": "{run.upper()}"' in line or f'"method":"{run.upper()}"' in line
                                       for line in lines)
