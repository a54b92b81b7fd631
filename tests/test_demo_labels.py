"""Demonstration labels are the poses the arm reached, in canonical form, and every task's expert
keyframes survive the policy's action coding: encode -> ideal logits -> decode -> execute succeeds."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from abm.data.generate import trainable_tasks
from abm.geometry import GRIPPER_REFERENCE_YAW_DEG, Workspace, canonical_gripper_matrix
from abm.policy import decode_output, encode_action
from abm.policy.heads import logits_from_targets
from abm.render import OrthographicRenderer
from abm.sim.arm_control import STOPPED
from abm.sim.tasks import get_task
from abm.types import KeyframeAction

RESOLUTION = 16  # camera pixels: these tests never look at the images
ALL_TASKS = trainable_tasks() + ["place_block_in_plate", "pick_food_to_target"]
LABEL_SEED = 3
REPLAY_SEEDS = (0, LABEL_SEED)  # the expert rollouts are shared (the ``expert_episode`` fixture)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(a.T @ b).magnitude()))


def _wrap_deg(angle: float) -> float:
    return (angle + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize("task", trainable_tasks())
def test_labels_are_reached_poses_in_canonical_form(task: str, expert_episode) -> None:
    # shared with test_oracle_replay_succeeds, which also reuses the environment (building it costs a rollout)
    episode = expert_episode(task, "seen", LABEL_SEED, RESOLUTION, keep_env=True)
    final_pose = expert_episode.final_tcp_pose(task, "seen", LABEL_SEED, RESOLUTION)
    assert episode.success, f"{task}: expert failed"
    kinds = [a.kind for _, a in episode.steps]
    assert "grasp" in kinds and all(kinds), kinds
    reached = [obs.gripper_pose for obs, _ in episode.steps[1:]] + [final_pose]
    for (_, act), pose in zip(episode.steps, reached, strict=True):
        label = act.matrix
        # the stored label is where the arm went (not its 180-degree flip)
        assert _angle_deg(label[:3, :3], pose[:3, :3]) < 5.0, (task, act.kind)
        assert np.linalg.norm(label[:3, 3] - pose[:3, 3]) < 0.01, (task, act.kind)
        # and it is the canonical member of its symmetry class
        assert _angle_deg(label[:3, :3], canonical_gripper_matrix(label[:3, :3], act.symmetry)) < 1e-3
        if label[2, 2] < -0.99:  # top-down keyframes: check the yaw range directly
            yaw = np.degrees(np.arctan2(label[1, 1], label[0, 1]))
            offset = abs(_wrap_deg(yaw - GRIPPER_REFERENCE_YAW_DEG))
            limit = 180.0 / act.symmetry + 1e-3 if act.symmetry else 1e-3  # 2: +-90, 4: +-45, 0: exact
            assert offset <= limit, (task, act.kind, act.symmetry, yaw)


def test_label_symmetry_follows_the_grasped_object(expert_episode) -> None:
    symmetries = {}
    for task in ("pick_block", "place_wine", "place_food"):
        episode = expert_episode(task, "seen", 0, RESOLUTION, keep_env=True)  # test_oracle_replay_succeeds too
        symmetries[task] = next(a.symmetry for _, a in episode.steps if a.kind == "grasp")
    # a cube turns by 90 degrees onto itself, a bottle by any angle, food boxes only by 180
    assert symmetries == {"pick_block": 4, "place_wine": 0, "place_food": 2}


def _through_action_coding(action: KeyframeAction, renderer: OrthographicRenderer) -> KeyframeAction:
    """The keyframe a perfect policy would output: encode, build ideal logits, decode."""
    enc = encode_action(action)
    out = logits_from_targets(torch.tensor(enc.position[None]), torch.tensor(enc.rotation_bins[None]),
                              [enc.gripper], [enc.collision], renderer)
    return decode_output(out, renderer)[0]


@pytest.mark.parametrize("task", ALL_TASKS)
def test_oracle_replay_succeeds(task: str, expert_episode) -> None:
    """Every task's expert keyframes, passed through the training preset's action coding (64-pixel
    views), still complete the task in the evaluation executor."""
    split = "compositional" if get_task(task).evaluation_only else "seen"
    renderer = OrthographicRenderer(Workspace(), resolution=64)
    for seed in REPLAY_SEEDS:
        keyframes = [a for _, a in expert_episode(task, split, seed, RESOLUTION, keep_env=True).steps]
        with expert_episode.replay_env(task, split, seed, RESOLUTION) as env:  # the rollout's scene, reset
            success = False
            for action in keyframes:
                _, success, info = env.step(_through_action_coding(action, renderer), render=False)
                assert info["motion"].status not in STOPPED, (task, seed, action.kind, info["motion"].message)
            assert success, f"{task} seed {seed}: decoded expert keyframes did not complete the task"
