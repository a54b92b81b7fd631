"""Tracking grounder: ground once, then carry the target's points forward (following the gripper)."""

from __future__ import annotations

import numpy as np
import pytest

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import build_grounder
from abm.grounding.grounders import OracleGrounder
from abm.grounding.mask_field import MaskField
from abm.grounding.tracking import TrackingGrounder
from abm.sim.env import TaskEnv, run_expert


@pytest.fixture(scope="module")
def rollout():
    """Clouds of every keyframe of one pick_block expert episode (grasp, lift, move, place...)."""
    with TaskEnv("pick_block", "seen", 0, resolution=64) as env:
        episode = run_expert(env)
    assert episode.success
    ws = Workspace()
    return episode, [(obs, fuse_cameras(obs, ws)) for obs, _ in episode.steps]


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a > 0.5, b > 0.5
    return float((a & b).sum() / max((a | b).sum(), 1))


class _FirstRightThenWrong:
    """Finds the target on its first call, then a distractor (a grounder whose answer jumps)."""

    name = "jumpy"

    def __init__(self, distractor: str) -> None:
        self.calls, self.oracle, self.distractor = 0, OracleGrounder(), distractor

    def ground(self, observation, cloud, target, object_names=None) -> MaskField:
        self.calls += 1
        return self.oracle.ground(observation, cloud, target if self.calls == 1 else self.distractor, object_names)


def test_tracking_follows_the_target_through_grasp_and_transport(rollout) -> None:
    episode, clouds = rollout
    target, names = episode.target_names[0], episode.object_names
    tracker = TrackingGrounder(OracleGrounder())
    oracle = OracleGrounder()
    ious = []
    for obs, cloud in clouds:
        tracked = tracker.ground(obs, cloud, target, names).mask
        ious.append(_iou(tracked, oracle.ground(obs, cloud, target, names).mask))
    assert tracker.inner_calls == 1, ious  # grounded once, tracked through lift, move and place
    assert min(ious) > 0.6 and np.mean(ious) > 0.8, ious


def test_tracking_keeps_the_first_answer_when_per_step_grounding_jumps(rollout) -> None:
    episode, clouds = rollout
    target, names = episode.target_names[0], episode.object_names
    distractor = next(n for n in names.values() if n not in (target, "target") and "block" in n)
    oracle = OracleGrounder()
    per_step = _FirstRightThenWrong(distractor)
    tracker = TrackingGrounder(_FirstRightThenWrong(distractor))
    for obs, cloud in clouds[:3]:
        truth = oracle.ground(obs, cloud, target, names).mask
        assert _iou(tracker.ground(obs, cloud, target, names).mask, truth) > 0.6
        last_per_step = per_step.ground(obs, cloud, target, names).mask
    assert _iou(last_per_step, truth) == 0.0  # the per-step answer jumped to the distractor


def test_reset_target_change_and_loss_of_track_reground(rollout) -> None:
    episode, clouds = rollout
    target, names = episode.target_names[0], episode.object_names
    obs, cloud = clouds[0]
    tracker = build_grounder({"kind": "tracking", "inner": {"kind": "oracle"}})
    assert isinstance(tracker, TrackingGrounder)
    tracker.ground(obs, cloud, target, names)
    tracker.ground(obs, cloud, target, names)
    assert tracker.inner_calls == 1
    tracker.ground(obs, cloud, "target", names)  # another target: ground again
    assert tracker.inner_calls == 2
    tracker.reset()
    tracker.ground(obs, cloud, "target", names)
    assert tracker.inner_calls == 3
    tracker.ground(obs, cloud, target, names)
    assert tracker.inner_calls == 4
    gone = ~OracleGrounder().ground(obs, cloud, target, names).mask.astype(bool)
    tracker.ground(obs, cloud.select(gone), target, names)  # the block was taken away
    assert tracker.inner_calls == 5  # lost: grounded again
    with pytest.raises(ValueError):
        TrackingGrounder(OracleGrounder(), radius=0.0)



class _Scored:
    """A graded grounder (like CLIP): heatmap ``first`` / ``later`` = (target score, distractor score); the
    mask is whichever scores higher."""

    name = "clip"

    def __init__(self, distractor: str, first: tuple[float, float], later: tuple[float, float]) -> None:
        self.calls, self.oracle, self.distractor, self.first, self.later = 0, OracleGrounder(), distractor, first, later

    def ground(self, observation, cloud, target, object_names=None) -> MaskField:
        self.calls += 1
        t_score, d_score = self.first if self.calls == 1 else self.later
        t = self.oracle.ground(observation, cloud, target, object_names).mask
        d = self.oracle.ground(observation, cloud, self.distractor, object_names).mask
        heat = (t_score * t + d_score * d).astype(np.float32)
        mask = (t if t_score > d_score else d).astype(np.float32)
        return MaskField(mask, heat, True, target, "")


def test_tracking_reacquires_when_the_tracked_score_falls(rollout) -> None:
    """A wrong first answer (the distractor scored a little higher) is dropped once the grounder scores the
    tracked object far below its new answer; a small difference keeps the track (hysteresis)."""
    episode, clouds = rollout
    target, names = episode.target_names[0], episode.object_names
    distractor = next(n for n in names.values() if n not in (target, "target") and "block" in n)
    oracle = OracleGrounder()
    obs, cloud = clouds[0]
    truth = oracle.ground(obs, cloud, target, names).mask
    wrong = oracle.ground(obs, cloud, distractor, names).mask

    tracker = TrackingGrounder(_Scored(distractor, first=(0.4, 0.5), later=(0.9, 0.2)), reacquire=True)
    assert _iou(tracker.ground(obs, cloud, target, names).mask, wrong) == 1.0  # the wrong first answer
    assert _iou(tracker.ground(obs, cloud, target, names).mask, truth) == 1.0  # its score fell: re-acquired
    assert tracker.reacquired == 1 and tracker.inner_calls == 2
    assert _iou(tracker.ground(obs, cloud, target, names).mask, truth) > 0.6  # and tracked from then on
    assert tracker.reacquired == 1

    steady = TrackingGrounder(_Scored(distractor, first=(0.4, 0.5), later=(0.5, 0.45)), reacquire=True)
    steady.ground(obs, cloud, target, names)
    assert _iou(steady.ground(obs, cloud, target, names).mask, wrong) > 0.6  # 0.45 >= 0.5 * 0.5: kept
    assert steady.reacquired == 0

    off = TrackingGrounder(_Scored(distractor, first=(0.4, 0.5), later=(0.9, 0.2)))  # off by default
    off.ground(obs, cloud, target, names)
    assert _iou(off.ground(obs, cloud, target, names).mask, wrong) > 0.6 and off.inner_calls == 1
    with pytest.raises(ValueError, match="reacquire_ratio"):
        TrackingGrounder(OracleGrounder(), reacquire_ratio=0.0)


def test_policy_and_evaluation_select_tracking(tiny_run) -> None:
    from abm.evaluation.runner import EvalSettings, _load_policy
    from abm.policy import KeyframePolicy
    from abm.train.synthetic import synthetic_episodes

    episodes = synthetic_episodes(2, camera_resolution=32)  # observations to act on (tiny_run: oracle-trained abm)
    policy = KeyframePolicy.from_checkpoint(tiny_run, grounder={"kind": "tracking"})
    assert policy.grounder_spec == {"kind": "tracking", "inner": {"kind": "oracle"}}
    obs, _ = episodes[0].steps[0]
    for _ in range(2):
        policy.act(obs, episodes[0].instruction, episodes[0].object_names)
    assert isinstance(policy.grounder, TrackingGrounder) and policy.grounder.inner_calls == 1
    policy.reset()  # a new episode grounds again
    policy.act(obs, episodes[0].instruction, episodes[0].object_names)
    assert policy.grounder.inner_calls == 2
    loaded = _load_policy(str(tiny_run), EvalSettings(grounder="tracking"))
    assert isinstance(loaded.grounder, TrackingGrounder)
    # --grounder clip --clip-model M: an oracle-trained policy grounds with that CLIP; tracking's first step too
    clip = _load_policy(str(tiny_run), EvalSettings(grounder="clip", clip_model="tiny"))
    assert clip.grounder_spec == {"kind": "clip", "model": "tiny"}
    tracked = _load_policy(str(tiny_run), EvalSettings(grounder="tracking", clip_model="tiny"))
    assert tracked.grounder_spec == {"kind": "tracking", "inner": {"kind": "clip", "model": "tiny"}}
    with pytest.raises(ValueError, match="--clip-model applies to --grounder clip or tracking"):
        EvalSettings(grounder="oracle", clip_model="tiny")
    assert "clip_model" not in EvalSettings().signature()  # outcomes recorded before the flag still match


def test_clip_model_override_keeps_the_trained_clip_options(tmp_path, tiny_policy) -> None:
    from abm.grounding.config import ClipGrounderConfig, OracleGrounderConfig, grounder_from_flags
    from abm.policy import KeyframePolicy
    from abm.train import TrainConfig, train
    from abm.train.synthetic import synthetic_episodes

    episodes = synthetic_episodes(2, camera_resolution=32)
    tiny = {k: v for k, v in tiny_policy.items() if k != "lang_dim"}  # the CLIP text width
    train(TrainConfig(out=tmp_path, steps=1, batch=2, policy=tiny, progress=False,
                      grounder=ClipGrounderConfig(model="tiny", threshold=0.4)), episodes)
    other = str(tmp_path / "elsewhere")  # a CLIP folder that was moved: only the model changes
    spec = KeyframePolicy.from_checkpoint(tmp_path, grounder=grounder_from_flags("tracking", "tiny")).grounder_spec
    assert spec == {"kind": "tracking", "inner": {"kind": "clip", "model": "tiny", "threshold": 0.4}}
    assert grounder_from_flags("clip", other) == ClipGrounderConfig(model=other)  # typed (abm.grounding.config)
    assert grounder_from_flags("clip", other).to_dict() == {"kind": "clip", "model": other}
    assert grounder_from_flags(None) is None and grounder_from_flags("oracle") == OracleGrounderConfig()
