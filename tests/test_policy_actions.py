"""Keyframe action encoding/decoding, translation targets, the loss and 3-D heatmap decoding."""

from __future__ import annotations

import numpy as np
import torch

from abm.geometry import Workspace, bins_to_quat, euler_to_quat, quat_angle_deg
from abm.policy import decode_action, decode_output, encode_action, policy_loss, translation_targets
from abm.policy.heads import logits_from_targets
from abm.render import OrthographicRenderer
from abm.types import KeyframeAction


def _random_actions(rng: np.random.Generator, n: int, workspace: Workspace) -> list[KeyframeAction]:
    out = []
    for _ in range(n):
        pos = rng.uniform(workspace.lower + 0.05, workspace.upper - 0.05)
        quat = euler_to_quat(rng.uniform(-180, 180, 3) * np.array([1.0, 0.45, 1.0]))
        out.append(KeyframeAction(pos, quat, bool(rng.integers(2)), bool(rng.integers(2))))
    return out


def test_encode_decode_round_trip() -> None:
    rng = np.random.default_rng(0)
    for action in _random_actions(rng, 20, Workspace()):
        enc = encode_action(action)
        dec = decode_action(enc.position, enc.rotation_bins, enc.gripper, enc.collision)
        np.testing.assert_allclose(dec.position, action.position, atol=1e-6)
        assert dec.gripper_open == action.gripper_open and dec.ignore_collision == action.ignore_collision
        assert quat_angle_deg(dec.quaternion, action.quaternion) < 2.5 * np.sqrt(3) + 1e-6
        # decoding then encoding again is exact
        assert np.array_equal(encode_action(dec).rotation_bins, enc.rotation_bins)
    bins = np.array([36, 30, 54])
    exact = KeyframeAction(np.zeros(3), bins_to_quat(bins), True)
    assert np.array_equal(encode_action(exact).rotation_bins, bins)


def test_translation_targets_peak_at_projection() -> None:
    renderer = OrthographicRenderer(Workspace(), resolution=48)
    pos = torch.tensor([[0.3, -0.2, 0.1], [0.7, 0.25, 0.5]])
    heat = translation_targets(renderer, pos, sigma=1.5)
    assert heat.shape == (2, 5, 48, 48)
    torch.testing.assert_close(heat.sum((-1, -2)), torch.ones(2, 5))
    uv, _ = renderer.project(pos)
    peak = heat.flatten(2).argmax(-1)
    rows, cols = peak // 48, peak % 48
    assert (cols - uv[..., 0]).abs().max() <= 0.5 + 1e-4 and (rows - uv[..., 1]).abs().max() <= 0.5 + 1e-4


def test_heads_round_trip_through_decoding() -> None:
    """Ideal logits built from targets decode back to the same action."""
    workspace = Workspace()
    for res in (48, 96):
        renderer = OrthographicRenderer(workspace, resolution=res)
        actions = _random_actions(np.random.default_rng(res), 6, workspace)
        enc = [encode_action(a) for a in actions]
        pos = torch.tensor(np.stack([e.position for e in enc]))
        bins = torch.tensor(np.stack([e.rotation_bins for e in enc]))
        out = logits_from_targets(pos, bins, [e.gripper for e in enc], [e.collision for e in enc], renderer)
        decoded = decode_output(out, renderer)
        px = workspace.size / res
        for a, e, d in zip(actions, enc, decoded, strict=True):
            assert np.linalg.norm(d.position - a.position) < 0.5 * px, (d.position, a.position)
            assert np.array_equal(encode_action(d).rotation_bins, e.rotation_bins)
            assert d.gripper_open == a.gripper_open and d.ignore_collision == a.ignore_collision


def test_loss_is_zero_for_perfect_prediction_and_positive_otherwise() -> None:
    renderer = OrthographicRenderer(Workspace(), resolution=32)
    pos = torch.tensor([[0.5, 0.0, 0.2]])
    bins = torch.tensor([[36, 36, 10]])
    grip, coll = torch.tensor([1]), torch.tensor([0])
    target = translation_targets(renderer, pos)
    ideal = logits_from_targets(pos, bins, grip, coll, renderer)
    terms = policy_loss(ideal, target, bins, grip, coll)
    assert terms.total.item() < 1e-4
    ideal.heatmap = torch.zeros_like(ideal.heatmap)
    assert policy_loss(ideal, target, bins, grip, coll).translation.item() > 1.0
