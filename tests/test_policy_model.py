"""Shapes and input checks of the multi-view transformer for every variant and preset."""

from __future__ import annotations

import pytest
import torch

from abm.policy import VARIANTS, MultiViewTransformer, PolicyConfig, check_compatible

LANG = 32
FEAT = 16


def _inputs(cfg: PolicyConfig, b: int) -> tuple[tuple, dict]:
    r, v = cfg.resolution, cfg.num_views
    args = (torch.randn(b, v, 10, r, r), torch.rand(b, 4), torch.randn(b, cfg.lang_tokens, cfg.lang_dim))
    kw: dict = {}
    if cfg.spec.uses_mask:
        kw["mask"] = torch.zeros(b, v, 1, r, r)
        kw["mask"][:, :, 0, r // 2, r // 2] = 1.0
    if cfg.spec.clip_features:
        kw["ifd_features"] = torch.randn(b, 50, cfg.ifd_feature_dim)
        kw["ifd_index"] = torch.randint(-1, 50, (b, v, r, r))
    return args, kw


def _check_out(out, cfg: PolicyConfig, b: int) -> None:
    r = cfg.resolution
    assert out.heatmap.shape == (b, cfg.num_views, r, r)
    assert out.rotation.shape == (b, 3, cfg.rotation_bins)
    assert out.gripper.shape == (b, 2)
    assert out.collision.shape == (b, 2)
    for t in (out.heatmap, out.rotation, out.gripper, out.collision):
        assert torch.isfinite(t).all()


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_small_preset_shapes(variant: str) -> None:
    cfg = PolicyConfig.from_preset("small", variant, lang_dim=LANG, ifd_feature_dim=FEAT)
    assert (cfg.resolution, cfg.patch_size, cfg.width, cfg.grid) == (96, 8, 128, 12)
    model = MultiViewTransformer(cfg)
    args, kw = _inputs(cfg, 2)
    out = model(*args, **kw)
    _check_out(out, cfg, 2)
    out.heatmap.sum().backward()  # every input path is differentiable


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_paper_preset_shapes_reduced_depth(variant: str) -> None:
    # paper view/patch/token geometry (5 x 220^2, 20 x 20 tokens), fewer/narrower layers to stay fast
    cfg = PolicyConfig.from_preset("paper", variant, layers_within=1, layers_joint=1, width=64, heads=4,
                                   stem_channels=8, lang_dim=LANG, ifd_feature_dim=FEAT)
    assert cfg.grid == 20 and cfg.preset == "paper+custom"
    model = MultiViewTransformer(cfg).eval()
    args, kw = _inputs(cfg, 1)
    with torch.no_grad():
        _check_out(model(*args, **kw), cfg, 1)


def test_paper_preset_full_size_forward() -> None:
    cfg = PolicyConfig.from_preset("paper", "abm")
    assert (cfg.resolution, cfg.patch_size, cfg.grid, cfg.width) == (220, 11, 20, 512)
    assert (cfg.layers_within, cfg.layers_joint, cfg.lang_tokens) == (4, 4, 77)
    model = MultiViewTransformer(cfg).eval()
    assert 25e6 < model.num_parameters() < 40e6
    args, kw = _inputs(cfg, 1)
    with torch.no_grad():
        _check_out(model(*args, **kw), cfg, 1)


def test_abm_without_mask_is_a_clear_error() -> None:
    cfg = PolicyConfig.from_preset("small", "abm", resolution=32, lang_dim=LANG)
    model = MultiViewTransformer(cfg)
    args, _ = _inputs(cfg, 1)
    with pytest.raises(ValueError, match="variant 'abm' needs a mask input"):
        model(*args)
    with pytest.raises(ValueError, match="mask must be"):
        model(*args, mask=torch.zeros(1, 5, 2, 32, 32))


def test_rvt_rejects_mask_and_bad_language() -> None:
    cfg = PolicyConfig.from_preset("small", "rvt", resolution=32, lang_dim=LANG)
    model = MultiViewTransformer(cfg)
    args, _ = _inputs(cfg, 1)
    with pytest.raises(ValueError, match="takes no mask"):
        model(*args, mask=torch.zeros(1, 5, 1, 32, 32))
    with pytest.raises(ValueError, match="language token embeddings"):
        model(args[0], args[1], torch.zeros(1, 10, LANG))


def test_ifd_needs_features() -> None:
    cfg = PolicyConfig.from_preset("small", "ifd", resolution=32, lang_dim=LANG, ifd_feature_dim=FEAT)
    args, _ = _inputs(cfg, 1)
    with pytest.raises(ValueError, match="needs ifd_features"):
        MultiViewTransformer(cfg)(*args)


def test_config_errors_and_compatibility() -> None:
    with pytest.raises(ValueError, match="unknown policy variant"):
        PolicyConfig.from_preset("small", "peract")
    with pytest.raises(ValueError, match="unknown preset"):
        PolicyConfig.from_preset("huge", "abm")
    with pytest.raises(ValueError, match="must divide"):
        PolicyConfig.from_preset("small", "abm", patch_size=7)
    small = PolicyConfig.from_preset("small", "abm")
    assert PolicyConfig.from_dict(small.to_dict()) == small
    with pytest.raises(ValueError, match="variant 'abm' but the model is 'rvt'"):
        check_compatible(small, PolicyConfig.from_preset("small", "rvt"))
    with pytest.raises(ValueError, match=r"^ck.pt: the checkpoint was trained with other policy settings than this "
                       r"model in 8 field\(s\): resolution: checkpoint 96, model 220; patch_size: .*width: checkpoint "
                       r"128, model 512;.* \(--set resolution=96 --set patch_size=8 --set width=128 .*\), or train"):
        check_compatible(small, PolicyConfig.from_preset("paper", "abm"), "ck.pt")
    custom = PolicyConfig.from_preset("small", "abm", width=64)  # both 'small+custom': the fields tell them apart
    with pytest.raises(ValueError, match=r"in 1 field\(s\): width: checkpoint 64, model 32\. .*--set width=64\)") \
            as err:
        check_compatible(custom, PolicyConfig.from_preset("small", "abm", width=32))
    assert "preset" not in str(err.value) and "small" not in str(err.value)
    check_compatible(small, PolicyConfig.from_dict({**small.to_dict(), "preset": "small+custom"}))  # a label only


@pytest.mark.parametrize("local", [False, True])
def test_local_rotation_features_tell_pixels_of_one_token_apart(local: bool) -> None:
    # two pooling points inside the same 8x8 patch: the token-level head cannot tell them apart, the
    # pixel-level decoder features can (and an old config without the field loads as token-only)
    cfg = PolicyConfig.from_preset("small", "abm", resolution=32, lang_dim=LANG, local_rotation_features=local)
    assert cfg.preset == "small+custom"
    data = cfg.to_dict()
    del data["local_rotation_features"]
    assert PolicyConfig.from_dict(data).local_rotation_features is False
    torch.manual_seed(0)
    model = MultiViewTransformer(cfg).eval()
    args, kw = _inputs(cfg, 1)
    outs = []
    for pixel in (8, 13):  # rows/cols 8 and 13 both lie in token (1, 1)
        weights = torch.zeros(1, cfg.num_views, 32, 32)
        weights[..., pixel, pixel] = 1.0
        with torch.no_grad():
            outs.append(model(*args, **kw, pool_weights=weights).rotation)
    assert torch.equal(outs[0], outs[1]) is not local
    extra = cfg.decoder_channels * cfg.num_views if local else 0
    assert model.global_head[0].in_features == 2 * cfg.width * cfg.num_views + extra


def test_a_block_restricted_to_the_first_queries_gives_their_outputs() -> None:
    """The last joint block computes only the view tokens' outputs (Block(x, queries=k)): the same values as the
    whole block's first k outputs, and gradients reach every token through the keys and values."""
    from abm.policy.mvt import Block

    torch.manual_seed(0)
    block = Block(32, 4, 2.0, 0.0)
    x = torch.randn(3, 20, 32, requires_grad=True)
    full = block(x)[:, :13]
    part = block(x, queries=13)
    assert part.shape == (3, 13, 32)
    torch.testing.assert_close(part, full, rtol=1e-5, atol=1e-6)
    grad_full = torch.autograd.grad(full.square().sum(), x)[0]
    grad_part = torch.autograd.grad(part.square().sum(), x)[0]
    torch.testing.assert_close(grad_part, grad_full, rtol=1e-5, atol=1e-6)
    assert grad_part[:, 13:].abs().sum() > 0  # the other tokens still matter, as keys and values
