"""The rotation head's crop reader (``PolicyConfig.rotation_crop``): where the crop is taken, what it sees, and that
it trains and round-trips in both one- and two-stage policies."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from abm.data.keyframes import KeyframeDataset, collate
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.language import HashLanguageEncoder
from abm.policy.mvt import MultiViewTransformer, _crop_at_mode
from abm.train.synthetic import synthetic_episodes

TINY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
        "decoder_channels": 4, "lang_dim": 16}
ZOOM = {"zoom_size": 0.2, "zoom_resolution": 16, "zoom_patch_size": 4}


def _policy(**overrides: object) -> KeyframePolicy:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "abm", **{**TINY, **overrides})
    return KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim))


def test_the_crop_is_centred_on_the_mode_and_zero_outside_the_map() -> None:
    maps = torch.arange(2 * 8 * 8, dtype=torch.float32).view(2, 8, 8, 1)  # value = 8 * row + col
    prob = torch.zeros(2, 8, 8)
    prob[0, 5, 6] = 1.0
    prob[1, 0, 0] = 0.6
    prob[1, 7, 7] = 0.4
    crops = _crop_at_mode(maps, prob, 4)
    assert crops.shape == (2, 1, 4, 4)
    np.testing.assert_array_equal(crops[0, 0].numpy(), maps[0, 3:7, 4:8, 0].numpy())  # rows/cols [c - 2, c + 2)
    # at the corner the crop is padded with zeros: only its bottom-right 2 x 2 lies inside the map
    expected = torch.zeros(4, 4)
    expected[2:, 2:] = maps[1, :2, :2, 0]
    np.testing.assert_array_equal(crops[1, 0].numpy(), expected.numpy())


def test_config_checks() -> None:
    for bad in (-4, 6, 40):
        with pytest.raises(ValueError, match="rotation_crop"):
            PolicyConfig.from_preset("small", "abm", **{**TINY, "rotation_crop": bad})
    with pytest.raises(ValueError, match="rotation_crop"):  # larger than the 16 px zoomed views
        PolicyConfig.from_preset("small", "abm", **{**TINY, **ZOOM, "rotation_crop": 20})
    cfg = PolicyConfig.from_preset("small", "abm", rotation_crop=16)
    assert cfg.preset == "small+custom"
    old = {k: v for k, v in PolicyConfig.from_preset("small", "abm").to_dict().items() if k != "rotation_crop"}
    assert PolicyConfig.from_dict(old).rotation_crop == 0  # configs saved before the option read as off


def test_the_head_reads_only_the_crop_around_the_pooled_pixel() -> None:
    """With the token features zeroed, the rotation logits change when the image changes inside the crop around
    the pooled pixel and not when it changes outside it (the crop is the head's only view of the pixels)."""
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "rvt", **{**TINY, "rotation_crop": 8})
    net = MultiViewTransformer(cfg).eval()
    assert net.global_head is not None
    with torch.no_grad():
        net.global_head[0].weight[:, :] = 0.0  # keep only the crop features' columns
        v, d = cfg.num_views, cfg.width
        per_view = 3 * d
        for view in range(v):
            cols = slice(view * per_view + 2 * d, (view + 1) * per_view)
            net.global_head[0].weight[:, cols] = torch.randn(d, d) * 0.1
    images = torch.randn(1, v, cfg.image_channels, 32, 32)
    pool = torch.zeros(1, v, 32, 32)
    pool[:, :, 10, 20] = 1.0
    args = (torch.zeros(1, cfg.proprio_dim), torch.zeros(1, cfg.lang_tokens, cfg.lang_dim))
    with torch.no_grad():
        base = net(images, *args, pool_weights=pool).rotation
        inside, outside = images.clone(), images.clone()
        inside[:, 0, :, 10, 20] += 1.0  # the pooled pixel of view 0
        outside[:, 0, :, 25, 5] += 1.0  # far outside its 8 px crop (and the stem's 3 x 3 reach)
        assert not torch.allclose(net(inside, *args, pool_weights=pool).rotation, base)
        assert torch.allclose(net(outside, *args, pool_weights=pool).rotation, base)


@pytest.mark.parametrize("zoom", [False, True], ids=["one-stage", "two-stage"])
def test_trains_and_round_trips(zoom: bool, tmp_path: Path) -> None:
    policy = _policy(rotation_crop=8, **(ZOOM if zoom else {}))
    head_net = policy.zoom_model if zoom else policy.model
    assert head_net is not None and head_net.crop_net is not None
    if zoom:
        assert policy.model.crop_net is None  # the coarse stage has no rotation head
    options = policy.sample_options()
    options.pop("features")
    ds = KeyframeDataset(synthetic_episodes(1, camera_resolution=32), policy.workspace, **options, augment=False)
    batch = collate([ds[0], ds[1]])
    policy.train()
    loss, _ = policy.compute_loss(batch)
    loss.backward()
    assert all(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in head_net.crop_net.parameters())
    policy.eval()
    before = policy.predict(batch)
    loaded = KeyframePolicy.from_checkpoint(policy.save(tmp_path / "policy.pt"))
    assert loaded.config.rotation_crop == 8
    for x, y in zip(before, loaded.predict(batch), strict=True):
        np.testing.assert_allclose(x.position, y.position, atol=1e-6)
        np.testing.assert_allclose(x.quaternion, y.quaternion, atol=1e-6)
