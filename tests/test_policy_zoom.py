"""The zoomed second stage (``PolicyConfig.zoom_size > 0``): geometry of the zoomed views, decoding through both
stages, training and checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abm.data.keyframes import KeyframeDataset, collate
from abm.geometry import quat_to_bins
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.heads import decode_output, logits_from_targets
from abm.policy.language import HashLanguageEncoder
from abm.policy.mvt import PolicyOutput
from abm.train.synthetic import synthetic_episodes

TINY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
        "decoder_channels": 4, "lang_dim": 16}
ZOOM = {"zoom_size": 0.2, "zoom_resolution": 16, "zoom_patch_size": 4}


def _policy(variant: str = "abm", **overrides: object) -> KeyframePolicy:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", variant, **TINY, **{**ZOOM, **overrides})
    return KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim))


@pytest.fixture(scope="module")
def batch() -> dict[str, object]:
    policy = _policy()
    options = policy.sample_options()
    options.pop("features")
    ds = KeyframeDataset(synthetic_episodes(1, camera_resolution=32), policy.workspace, **options, augment=False)
    return collate([ds[0], ds[1]])


def test_config_checks_and_defaults() -> None:
    one = PolicyConfig.from_preset("small", "abm")
    assert not one.two_stage and one.zoom_size == 0.0
    with pytest.raises(ValueError, match="one stage"):
        one.zoom_config()
    with pytest.raises(ValueError, match="zoom_patch_size 5 must divide"):
        PolicyConfig.from_preset("small", "abm", zoom_size=0.2, zoom_resolution=16, zoom_patch_size=5)
    with pytest.raises(ValueError, match="zoom_noise"):
        PolicyConfig.from_preset("small", "abm", zoom_size=0.2, zoom_noise=0.15)
    with pytest.raises(ValueError, match="zoom_size"):
        PolicyConfig.from_preset("small", "abm", zoom_size=-0.1)
    two = PolicyConfig.from_preset("small", "rvt", **ZOOM)
    assert two.preset == "small+custom" and two.two_stage
    fine = two.zoom_config()
    assert (fine.resolution, fine.patch_size, fine.workspace_size, fine.workspace_center, fine.zoom_size) == (
        16, 4, 0.2, (0.0, 0.0, 0.0), 0.0)
    # a config saved before the zoom existed (no zoom keys) reads as one stage
    old = {k: v for k, v in one.to_dict().items() if not k.startswith("zoom")}
    assert PolicyConfig.from_dict(old) == one


def test_a_point_rendered_in_the_zoom_lands_at_its_centre(batch: dict[str, object]) -> None:
    policy = _policy()
    points = batch["points"]
    assert isinstance(points, torch.Tensor)
    center = points[:, 0].clone()  # zoom on the first point of each sample's cloud
    inputs = policy.model_inputs(batch, zoom_center=center)
    res = policy.config.zoom_resolution
    images = inputs["images"]  # (B, V, 10, h, w)
    assert images.shape[-2:] == (res, res)
    # the centre of the zoom projects between the four middle pixels; the point itself is rendered into one of
    # them in every view (it may be hidden by a nearer point in some views, but then a point within one pixel
    # of it in the view plane is shown)
    mid = slice(res // 2 - 1, res // 2 + 1)
    xyz = images[:, :, 4:7, mid, mid]  # relative to the centre
    occupied = images[:, :, 3, mid, mid] < policy.config.zoom_size - 1e-6
    assert occupied.any(-1).any(-1).all()
    pixel = policy.config.zoom_size / res
    for b in range(xyz.shape[0]):
        for v in range(xyz.shape[1]):
            axes = policy.zoom_renderer.axes[v, :2]  # the view plane's two axes
            plane = torch.einsum("chw,jc->jhw", xyz[b, v], axes)
            near = (plane.abs() <= pixel + 1e-6).all(0) & occupied[b, v]
            assert near.any(), (b, v)
    # and the target Gaussian of the label at the centre peaks there
    from abm.policy.heads import translation_targets

    target = translation_targets(policy.zoom_renderer, torch.zeros(1, 3))
    peak = target[0].flatten(1).argmax(-1)
    rows, cols = peak // res, peak % res
    assert set(rows.tolist()) <= {res // 2 - 1, res // 2} and set(cols.tolist()) <= {res // 2 - 1, res // 2}


def test_known_actions_decode_exactly_through_both_stages() -> None:
    policy = _policy()
    positions = torch.tensor([[0.52, -0.11, 0.18], [0.31, 0.24, 0.42]])
    quats = np.array([[0.0, 1.0, 0.0, 0.0], [0.2705981, 0.6532815, -0.2705981, 0.6532815]])
    bins = torch.from_numpy(np.asarray(quat_to_bins(quats, policy.config.rotation_bins), np.int64).reshape(-1, 3))
    coarse = logits_from_targets(positions, bins, [1, 0], [0, 1], policy.renderer)
    # the coarse point is off by up to a few cm; the zoomed stage's heatmap is centred on the true point
    center = positions + torch.tensor([[0.03, -0.02, 0.01], [-0.04, 0.0, 0.035]])
    fine = logits_from_targets(positions - center, bins, [1, 0], [0, 1], policy.zoom_renderer)
    out = PolicyOutput(fine.heatmap, fine.rotation, fine.gripper, fine.collision, coarse_heatmap=coarse.heatmap,
                       zoom_center=center)
    actions = decode_output(out, policy.renderer, policy.zoom_renderer)
    for a, p, q in zip(actions, positions.numpy(), quats, strict=True):
        # the zoom's pixel is 0.2 m / 16 = 12.5 mm; sub-pixel decoding recovers the point to a fraction of it
        assert np.linalg.norm(a.position - p) < 2e-3
        assert abs(abs(float(np.dot(a.quaternion, q))) - 1.0) < 2e-3
    assert [a.gripper_open for a in actions] == [True, False]
    with pytest.raises(ValueError, match="zoom_renderer"):
        decode_output(out, policy.renderer)


def test_training_step_reaches_both_stages_and_only_the_zoom_has_a_rotation_head(batch: dict[str, object]) -> None:
    policy = _policy().train()
    assert policy.model.global_head is None and policy.zoom_model is not None
    loss, metrics = policy.compute_loss(batch)
    assert torch.isfinite(loss) and float(metrics["zoom_translation"]) > 0 and float(metrics["translation"]) > 0
    total = sum(float(metrics[k]) for k in ("translation", "zoom_translation", "rotation", "gripper", "collision"))
    assert float(metrics["total"]) == pytest.approx(total, rel=1e-5)
    loss.backward()
    for name, net in (("coarse", policy.model), ("zoom", policy.zoom_model)):
        grads = [p.grad for p in net.parameters()]
        assert all(g is not None for g in grads), name  # every parameter is used (DDP needs it)
        assert any(float(g.abs().sum()) > 0 for g in grads if g is not None), name
    # the training noise moves the zoom centre; in eval mode the centre is the label
    policy.eval()
    with torch.no_grad():
        a = policy.compute_loss(batch)[1]["zoom_translation"]
        b = policy.compute_loss(batch)[1]["zoom_translation"]
    assert float(a) == float(b)


def test_a_single_stage_policy_has_no_zoom(batch: dict[str, object]) -> None:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "abm", **TINY)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim)).eval()
    assert policy.zoom_model is None and policy.zoom_renderer is None
    assert "zoom_model" not in policy.checkpoint_payload()
    with pytest.raises(ValueError, match="one-stage"):
        policy.model_inputs(batch, zoom_center=torch.zeros(2, 3))
    _, metrics = policy.compute_loss(batch)
    assert float(metrics["zoom_translation"]) == 0.0


@pytest.mark.parametrize("variant", ["abm", "rvt", "ifd", "concat-full"])
def test_checkpoint_round_trip_predicts_the_same(variant: str, tmp_path: object, batch: dict[str, object]) -> None:
    from pathlib import Path

    policy = _policy(variant, **({"ifd_feature_dim": 8} if variant == "ifd" else {})).eval()
    samples = dict(batch)
    if variant == "ifd":  # stand-in CLIP point features
        points = samples["points"]
        assert isinstance(points, torch.Tensor)
        samples["feature_table"] = torch.cat([points, points.flip(-1), points[..., :2]], -1)  # (B, N, 8)
        samples["feature_row"] = torch.arange(points.shape[1]).expand(points.shape[0], -1)
    if policy.sample_options()["mask"] is False:
        samples.pop("point_mask", None)
        samples.pop("point_heatmap", None)
    before = policy.predict(samples)
    path = policy.save(Path(str(tmp_path)) / "policy.pt")
    loaded = KeyframePolicy.from_checkpoint(path)
    assert loaded.config == policy.config and loaded.zoom_model is not None
    after = loaded.predict(samples)
    for x, y in zip(before, after, strict=True):
        np.testing.assert_allclose(x.position, y.position, atol=1e-6)
        np.testing.assert_allclose(x.quaternion, y.quaternion, atol=1e-6)
    # a checkpoint without the zoomed stage's weights does not load into a two-stage policy
    payload = policy.checkpoint_payload()
    del payload["zoom_model"]
    with pytest.raises(ValueError, match="no zoomed stage"):
        _policy(variant, **({"ifd_feature_dim": 8} if variant == "ifd" else {})).load_networks(payload)
