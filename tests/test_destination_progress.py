"""The destination mask and the progress input (issue 53, items 1 and 2).

Every task declares where it brings X (``Task.destination``); the resolver and the conditioning name it; the same
grounders ground it into a second mask field; ``PolicyConfig.destination_mask`` gives the mask variants a second
mask channel and ``PolicyConfig.progress_input`` adds the keyframe index to every variant's proprioception. Both
are off by default, and checkpoints written without them load with them off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from abm.geometry import Workspace, fuse_cameras
from abm.grounding.config import ClipGrounderConfig, OracleGrounderConfig
from abm.grounding.grounders import OracleGrounder
from abm.grounding.tracking import TrackingGrounder
from abm.language.roles import destination_for, instruction_destination
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.keyframe_policy import proprioception
from abm.render.synthetic import synthetic_scene
from abm.samples import collate
from abm.sim.tasks import TASKS
from abm.train.synthetic import synthetic_episodes
from conftest import TINY_POLICY as TINY

OLD_RUN = Path(__file__).parent / "data" / "checkpoints_v1" / "run_oracle"

#: one instruction per task (the task's first template) and the destination the resolver must name
DESTINATIONS = {
    "pick_block": ("put the yellow block on the target", "target"),
    "pick_food_to_target": ("put the cookies on the target", "target"),
    "place_food": ("put the cookies in the plate", "plate"),
    "place_block_in_plate": ("put the blue block in the plate", "plate"),
    "place_wine": ("put the wine bottle in the wine rack", "wine rack"),
    "put_in_shelf": ("put the cookies on the top shelf", "shelf"),
    "close_jar": ("close the green jar", "green jar"),
    "insert_peg": ("put the ring on the yellow peg", "yellow peg"),
    "water_plants": ("water the plant with the white mug", "plant"),
    "put_in_container": ("place the cookies into the white bowl", "white bowl"),
    "take_off_pan": ("take the butter off the frypan", None),
}


# ----------------------------------------------------------------------------------------- declarations, resolver
def test_every_task_declares_its_destination() -> None:
    assert set(DESTINATIONS) == set(TASKS)
    for name, task in TASKS.items():
        assert task.destination is None or isinstance(task.destination, str), name
    assert TASKS["take_off_pan"].destination is None  # X goes onto the free table: no destination object
    assert TASKS["close_jar"].destination_name(("red jar",)) == "red jar"  # X itself
    assert TASKS["put_in_container"].destination_name(("milk", "basket")) == "basket"  # Y


@pytest.mark.parametrize("task", sorted(DESTINATIONS))
def test_the_resolver_names_each_tasks_destination(task: str) -> None:
    from abm.language.resolve import resolve_instruction

    text, want = DESTINATIONS[task]
    instance = TASKS[task]().sample(0, "compositional" if TASKS[task].evaluation_only else "seen")
    assert instance.instruction == text  # the scene of seed 0 (kept in step with the task's sampling)
    resolution = resolve_instruction(text, list(instance.scene.object_names.values()))
    assert resolution.destination == want
    assert resolution.as_record()["destination"] == want
    assert instruction_destination(text) == want  # what a policy's conditioning grounds at run time
    if task == "put_in_container":
        assert resolution.destination == resolution.second  # the two-target skill's Y is its destination


def test_destination_of_tasks_that_disagree_or_are_unknown() -> None:
    assert destination_for(("pick_block", "place_food"), ("x",)) is None  # the tasks disagree: none
    assert destination_for((), ("ketchup", "bowl")) == "bowl"  # a user's two-target skill: Y
    assert destination_for((), ("ketchup",)) is None
    assert instruction_destination("do a little dance") is None  # no template


# ----------------------------------------------------------------------------------------------------- config
def test_config_defaults_are_off_and_checked() -> None:
    config = PolicyConfig()
    assert config.destination_mask is False and config.progress_input is False
    assert config.mask_channels == 1 and config.proprio_size == config.proprio_dim == 4
    both = PolicyConfig(destination_mask=True, progress_input=True)
    assert both.mask_channels == 2 and both.proprio_size == 5
    assert PolicyConfig(variant="rvt", progress_input=True).proprio_size == 5  # progress: every variant
    assert PolicyConfig(variant="rvt").mask_channels == 0
    with pytest.raises(ValueError, match="variant 'rvt' takes no mask"):
        PolicyConfig(variant="rvt", destination_mask=True)
    with pytest.raises(ValueError, match="progress_budget"):
        PolicyConfig(progress_budget=0)
    assert PolicyConfig.from_dict(both.to_dict()) == both


def test_a_checkpoint_without_the_fields_loads_with_them_off() -> None:
    stored = torch.load(sorted(OLD_RUN.rglob("*.pt"))[-1], weights_only=True)["policy_config"]
    assert "destination_mask" not in stored and "progress_input" not in stored  # written before them
    policy = KeyframePolicy.from_checkpoint(OLD_RUN)
    assert policy.config.destination_mask is False and policy.config.progress_input is False
    assert policy.model.proprio.in_features == 4
    assert policy.sample_options()["destination"] is False


def test_proprioception_feeds_the_keyframe_index_over_the_budget() -> None:
    batch = {"gripper_open": torch.tensor([1.0, 0.5, 0.0]), "gripper_position": torch.zeros(3, 3),
             "keyframe_index": torch.tensor([0, 4, 20])}
    ws = Workspace((0.0, 0.0, 0.0), 2.0)
    off = proprioception(batch, PolicyConfig(), ws, torch.device("cpu"))
    assert off.shape == (3, 4)
    on = proprioception(batch, PolicyConfig(progress_input=True, progress_budget=8), ws, torch.device("cpu"))
    assert on.shape == (3, 5)
    np.testing.assert_allclose(on[:, 4].numpy(), [0.0, 0.5, 1.0])  # 20 / 8 is clipped to 1
    np.testing.assert_allclose(on[:, :4].numpy(), off.numpy())
    with pytest.raises(ValueError, match="keyframe_index"):
        proprioception({k: v for k, v in batch.items() if k != "keyframe_index"},
                       PolicyConfig(progress_input=True), ws, torch.device("cpu"))


# -------------------------------------------------------------------------------------------------- grounders
def test_tracking_keeps_the_targets_track_while_grounding_the_destination() -> None:
    obs, names = synthetic_scene(seed=0, resolution=40)
    cloud = fuse_cameras(obs, Workspace())
    target, destination = sorted(names.values())[:2]
    tracker = TrackingGrounder(OracleGrounder())
    for _ in range(3):
        t = tracker.ground(obs, cloud, target, names)
        d = tracker.ground_destination(obs, cloud, destination, names)
    assert tracker.inner_calls == 2  # one start per track; alternating never restarts the target's
    oracle = OracleGrounder()
    np.testing.assert_array_equal(t.mask, oracle.ground(obs, cloud, target, names).mask)
    np.testing.assert_array_equal(d.mask, oracle.ground(obs, cloud, destination, names).mask)
    tracker.reset()
    tracker.ground(obs, cloud, target, names)
    assert tracker.inner_calls == 3


def test_cached_clip_grounding_fills_and_reads_the_destination_entries(tmp_path: Path) -> None:
    from abm.data.keyframes import KeyframeDataset, ground_keyframes

    episodes = synthetic_episodes(1, camera_resolution=32)
    ws = Workspace()
    clip = ClipGrounderConfig(model="tiny", device="cpu", mode="field")
    made = ground_keyframes(episodes, ws, clip, tmp_path, destination=True, augment=False, show_progress=False)
    assert made == 2
    assert len(list(tmp_path.glob("*.npz"))) == 4  # the target's and the destination's ("target") per keyframe
    ds = KeyframeDataset(episodes, ws, clip, mask=True, destination=True, augment=False, cache_dir=tmp_path)
    assert ds.destinations == ["target"]  # the instruction's words, as CLIP reads them
    sample = ds[1]
    assert sample["destination_mask"].shape == sample["point_mask"].shape
    assert int(sample["keyframe_index"]) == 1
    with pytest.raises(Exception, match="lacks 2 of 2"):  # a cache without the destination entries is refused
        KeyframeDataset(episodes, ws, clip, mask=True, destination=True, augment=False, cache_dir=tmp_path / "none")


# ------------------------------------------------------------------- a recorded pick_block scene (simulator)
@pytest.fixture(scope="module")
def pick_block():
    """A recorded pick_block demonstration (cameras 64 px) and the pad's and block's world centres at its start."""
    from sim_helpers import require_simulator

    require_simulator()
    from abm.sim.env import make_env, run_expert

    with make_env("pick_block", "seen", 0, 64) as env:
        env.reset()
        sim = env._require_sim()
        centres = {name: sim.object_pose(i)[:3, 3].copy() for i, name in env.object_names.items()}
        episode = run_expert(env)
    return episode, centres


def _pixel(policy: KeyframePolicy, point: np.ndarray, view: int) -> tuple[int, int]:
    uv, _ = policy.renderer.project(torch.as_tensor(point, dtype=torch.float32)[None])
    u, v = uv[0, view].round().long().tolist()
    return v, u  # (row, column)


def test_the_destination_mask_covers_the_target_pad_not_the_block(pick_block) -> None:
    episode, centres = pick_block
    obs = episode.steps[0][0]
    assert episode.target_names == ["yellow block"]
    config = PolicyConfig.from_preset("small", "concat-full", destination_mask=True)
    policy = KeyframePolicy(config, {"kind": "hash", "dim": config.lang_dim}, OracleGrounderConfig())
    sample = policy.observe(obs, episode.instruction, episode.object_names)
    assert sample["destination_mask"].sum() > 0 and sample["point_mask"].sum() > 0
    assert not bool((sample["destination_mask"] * sample["point_mask"]).any())  # no point is both
    mask = policy.model_inputs(collate([sample]))["mask"][0]  # (V, 2, H, W): the block's channel, the pad's
    assert mask.shape[:2] == (5, 2)
    top = list(config.views).index("top")
    pad, block = _pixel(policy, centres["target"], top), _pixel(policy, centres["yellow block"], top)
    assert mask[top, 1][pad] == 1 and mask[top, 0][pad] == 0  # the pad's centre: destination only
    assert mask[top, 0][block] == 1 and mask[top, 1][block] == 0  # the block's centre: target only
    # the pad (a 10 cm square seen from above at 96 px over 1 m: ~92 pixels) is the destination
    assert 60 <= int(mask[top, 1].sum()) <= 200


def test_train_save_load_predict_with_both_switches(pick_block, tmp_path: Path) -> None:
    from abm.train import TrainConfig, train

    episode, _ = pick_block
    overrides = {**TINY, "destination_mask": True, "progress_input": True}
    cfg = TrainConfig(method="abm", preset="small", out=tmp_path / "run", steps=2, batch=2, checkpoint_every=2,
                      log_every=1, policy=overrides, progress=False, warmup=1)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train(cfg, [episode])
    finally:
        torch.set_num_threads(threads)
    policy = KeyframePolicy.from_checkpoint(tmp_path / "run")
    assert policy.config.destination_mask and policy.config.progress_input
    assert policy.model.proprio.in_features == 5 and policy.model.fuse[0].in_channels == TINY["stem_channels"] + 2
    obs = episode.steps[3][0]  # before the move: holding the block
    seen = policy.explain(obs, episode.instruction, episode.object_names)
    assert seen.view_destination_mask is not None and seen.view_destination_mask.sum() >= 1  # abm: centre pixels
    assert np.isfinite(seen.action.position).all()
    # the keyframe index reaches the network: another step index, another prediction
    sample = policy.observe(obs, episode.instruction, episode.object_names)
    later = {**sample, "keyframe_index": torch.tensor(7)}
    out = [policy.infer(collate([s]))[0].heatmap for s in (sample, later)]
    assert not torch.allclose(out[0], out[1])
