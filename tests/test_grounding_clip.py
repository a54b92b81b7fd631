"""CLIP backbone: MaskCLIP dense features, text features, loading and its errors (tiny random model)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("transformers")

import abm.grounding.clip as clip_module  # noqa: E402
from abm.grounding.clip import (  # noqa: E402
    TEXT_CONTEXT,
    ClipWeightsNotFoundError,
    build_config,
    load_clip,
    model_fingerprint,
    tiny_clip,
)
from abm.grounding.grounders import resolved_spec  # noqa: E402


@pytest.fixture(scope="module")
def clip():
    return tiny_clip(seed=0)


@pytest.fixture(scope="module")
def images():
    return np.random.default_rng(1).integers(0, 256, size=(3, 40, 52, 3), dtype=np.uint8)


def _linear(x: torch.Tensor, layer: torch.nn.Linear) -> torch.Tensor:
    out = x @ layer.weight.T
    return out + layer.bias if layer.bias is not None else out


def _layer_norm(x: torch.Tensor, ln: torch.nn.LayerNorm) -> torch.Tensor:
    mu = x.mean(-1, keepdim=True)
    var = ((x - mu) ** 2).mean(-1, keepdim=True)
    return (x - mu) / torch.sqrt(var + ln.eps) * ln.weight + ln.bias


def test_maskclip_matches_hand_computation(clip, images):
    feats = clip.dense_features(images)
    g = clip.grid_size
    assert feats.shape == (3, g, g, clip.embed_dim)
    with torch.no_grad():
        pixels = clip.preprocess(images)
        vision = clip.model.vision_model
        hidden = vision(pixel_values=pixels, output_hidden_states=True).hidden_states
        x = hidden[-2]  # the input of the last block: every earlier block ran normally
        last = vision.encoder.layers[-1]
        v = _linear(_layer_norm(x, last.layer_norm1), last.self_attn.v_proj)
        y = _linear(v, last.self_attn.out_proj)[:, 1:]  # no attention mixing, residual or MLP; CLS dropped
        y = _layer_norm(y, vision.post_layernorm) @ clip.model.visual_projection.weight.T
        y = y / y.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(feats, y.reshape(3, g, g, -1), atol=1e-5, rtol=1e-5)
    assert torch.allclose(feats.norm(dim=-1), torch.ones(3, g, g), atol=1e-5)


def test_maskclip_is_not_the_standard_last_block(clip, images):
    """Sanity check that the value-only path differs from running the last block normally."""
    with torch.no_grad():
        pixels = clip.preprocess(images)
        vision = clip.model.vision_model
        out = vision(pixel_values=pixels).last_hidden_state[:, 1:]
        std = F.normalize(clip.model.visual_projection(vision.post_layernorm(out)), dim=-1)
    assert not torch.allclose(std.reshape(clip.dense_features(images).shape), clip.dense_features(images))


def test_preprocess_resizes_any_size_and_list_input(clip):
    a = np.zeros((30, 30, 3), np.uint8)
    b = np.full((100, 70, 3), 255, np.uint8)
    px = clip.preprocess([a, b])
    assert px.shape == (2, 3, clip.image_size, clip.image_size)
    mean = torch.tensor(clip.image_mean).view(3, 1, 1)
    std = torch.tensor(clip.image_std).view(3, 1, 1)
    torch.testing.assert_close(px[0], ((0 - mean) / std).expand(3, clip.image_size, clip.image_size))
    torch.testing.assert_close(px[1], ((1 - mean) / std).expand(3, clip.image_size, clip.image_size))
    with pytest.raises(ValueError, match="multiple of the patch size"):
        clip.preprocess([a], input_size=(30, 30))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        clip.preprocess([np.zeros((5, 5), np.uint8)])


def test_non_native_input_size_interpolates_position_embeddings(clip, images):
    p = clip.patch_size
    feats = clip.dense_features(images, input_size=(6 * p, 10 * p))
    assert feats.shape == (3, 6, 10, clip.embed_dim)
    assert torch.isfinite(feats).all()


def test_batching_does_not_change_features(clip, images):
    together = clip.dense_features(images)
    alone = torch.cat([clip.dense_features(images[i:i + 1]) for i in range(3)])
    torch.testing.assert_close(together, alone, atol=1e-5, rtol=1e-5)


def test_text_features_and_tokens(clip):
    prompts = ["a photo of a tomato", "a photo of an orange juice"]
    feats = clip.text_features(prompts)
    assert feats.shape == (2, clip.embed_dim)
    assert torch.allclose(feats.norm(dim=-1), torch.ones(2), atol=1e-5)
    assert not torch.allclose(feats[0], feats[1])
    with torch.no_grad():
        enc = clip.tokenize(prompts)
        out = clip.model.text_model(**enc)
        manual = F.normalize(clip.model.text_projection(out.pooler_output), dim=-1)
    torch.testing.assert_close(feats, manual)  # padded to 77 tokens there, to the longest prompt here
    torch.testing.assert_close(clip.text_features(prompts[:1])[0], feats[0])  # another padding length
    tokens = clip.text_tokens(["put X in the plate", "close X"])
    assert tokens.shape == (2, TEXT_CONTEXT, clip.text_width)
    torch.testing.assert_close(clip.text_tokens(["close X"])[0], tokens[1])


def test_tiny_model_is_deterministic(clip, images):
    again = tiny_clip(seed=0)
    torch.testing.assert_close(again.dense_features(images), clip.dense_features(images))
    other = tiny_clip(seed=1)
    assert not torch.allclose(other.dense_features(images), clip.dense_features(images))


def test_local_directory_round_trip(clip, images, tmp_path):
    clip.model.save_pretrained(tmp_path)
    clip.tokenizer.save_pretrained(tmp_path)
    loaded = load_clip(str(tmp_path), device="cpu")
    torch.testing.assert_close(loaded.dense_features(images), clip.dense_features(images))
    torch.testing.assert_close(loaded.text_features(["a photo of a cup"]), clip.text_features(["a photo of a cup"]))


def test_cache_keys_name_a_local_model_by_content_not_by_path(clip, tmp_path):
    def save(backbone, folder):
        backbone.model.save_pretrained(folder)
        backbone.tokenizer.save_pretrained(folder)
        (folder / "train_log.csv").write_text("step,loss\n")  # notes beside the weights do not count

    save(clip, tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "moved")
    (tmp_path / "moved" / "train_log.csv").write_text("step,loss\n1,2\n")
    first = model_fingerprint(str(tmp_path / "a"))
    assert first.startswith("sha256:") and model_fingerprint(str(tmp_path / "moved")) == first
    assert load_clip(str(tmp_path / "moved"), device="cpu").fingerprint == first
    spec = {"kind": "clip", "model": str(tmp_path / "a"), "mode": "proposals"}
    moved = {**spec, "model": str(tmp_path / "moved")}
    assert resolved_spec(spec) == resolved_spec(moved)
    save(tiny_clip(seed=1), tmp_path / "a")  # retrained into the same folder: its cache entries are new ones
    clip_module._fingerprints.clear()  # (the memo is keyed by modification times, which a coarse clock may repeat)
    assert model_fingerprint(str(tmp_path / "a")) != first
    assert resolved_spec(spec) != resolved_spec(moved)
    assert model_fingerprint("tiny") == "tiny" and model_fingerprint(str(tmp_path / "none")) == str(tmp_path / "none")


def test_missing_weights_explain_how_to_provide_them(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf" / "hub"))
    with pytest.raises(ClipWeightsNotFoundError) as err:
        load_clip("openai/clip-vit-large-patch14-336", device="cpu")
    message = str(err.value)
    assert "huggingface-cli download openai/clip-vit-large-patch14-336" in message
    assert "HF_HOME" in message and "local directory" in message and "\n" not in message
    with pytest.raises(ClipWeightsNotFoundError, match="config.json"):
        load_clip(str(tmp_path / "no_such_dir"))
    assert issubclass(ClipWeightsNotFoundError, FileNotFoundError)


def test_missing_weights_are_one_error_line_of_the_command(tmp_path, capsys):
    from abm.cli import main

    missing = tmp_path / "no_such_dir"
    assert main(["ground", "--grounder", "clip", "--clip-model", str(missing), "--resolution", "32",
                 "--out", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"abm: error: CLIP weights '{missing}' are not available")
    assert "abm clip train --out DIR" in err[0] and "huggingface-cli" not in err[0]  # a folder: no hub advice


def test_presets_have_the_real_architectures():
    b16 = build_config("vit-b16")
    assert (b16.vision_config.image_size, b16.vision_config.patch_size, b16.projection_dim) == (224, 16, 512)
    l14 = build_config("vit-l14-336")
    assert (l14.vision_config.image_size, l14.vision_config.patch_size, l14.vision_config.hidden_size,
            l14.vision_config.num_hidden_layers, l14.projection_dim) == (336, 14, 1024, 24, 768)
    with pytest.raises(ValueError, match="unknown CLIP preset"):
        build_config("vit-h14")


@pytest.mark.parametrize("act", ["quick_gelu", "gelu"])
def test_fast_encoder_layer_matches_the_library_layer(act):
    """The encoder layer that folds quick_gelu's 1.702 into the matmuls computes the library's layer."""
    from transformers import CLIPVisionConfig
    from transformers.models.clip.modeling_clip import CLIPEncoderLayer

    from abm.grounding.clip import run_encoder_layer

    torch.manual_seed(0)
    cfg = CLIPVisionConfig(hidden_size=32, intermediate_size=64, num_attention_heads=4, hidden_act=act)
    layer = CLIPEncoderLayer(cfg).eval()
    x = torch.randn(2, 5, 32)
    with torch.no_grad():
        ref = layer(x, None)
        ref = ref[0] if isinstance(ref, tuple) else ref
        got = run_encoder_layer(layer, x.clone())
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)


# ---- dense-feature variants of the last block (issue 26, part 1) ----------------------------------
def _last_block_input(clip, images):
    with torch.no_grad():
        pixels = clip.preprocess(images)
        vision = clip.model.vision_model
        x = vision(pixel_values=pixels, output_hidden_states=True).hidden_states[-2]
    return x, vision.encoder.layers[-1], vision


def _project(clip, vision, y):
    y = _layer_norm(y[:, 1:], vision.post_layernorm) @ clip.model.visual_projection.weight.T
    return y / y.norm(dim=-1, keepdim=True)


def _heads(t, heads):
    b, n, w = t.shape
    return t.reshape(b, n, heads, w // heads).transpose(1, 2)


def test_maskclip_mode_is_todays_output(clip, images):
    torch.testing.assert_close(clip.dense_features(images, mode="maskclip"), clip.dense_features(images),
                               atol=0, rtol=0)


@pytest.mark.parametrize("mode", ["clearclip", "sclip"])
def test_clearclip_and_sclip_match_hand_computation_without_residual(clip, images, mode):
    """Query-query (ClearCLIP) / query-query + key-key (SCLIP) attention over the values, then out_proj only:
    no residual and no MLP, so the block's input x enters only through the attention and the values."""
    x, last, vision = _last_block_input(clip, images)
    heads = last.self_attn.num_heads
    with torch.no_grad():
        h = _layer_norm(x, last.layer_norm1)
        q = _heads(_linear(h, last.self_attn.q_proj), heads)
        k = _heads(_linear(h, last.self_attn.k_proj), heads)
        v = _heads(_linear(h, last.self_attn.v_proj), heads)
        s = q.shape[-1] ** -0.5
        att = torch.softmax(q @ q.transpose(-1, -2) * s, -1)
        if mode == "sclip":
            att = att + torch.softmax(k @ k.transpose(-1, -2) * s, -1)
        y = _linear((att @ v).transpose(1, 2).reshape(x.shape), last.self_attn.out_proj)
        ref = _project(clip, vision, y)
        with_residual = _project(clip, vision, x + y)
    g = clip.grid_size
    got = clip.dense_features(images, mode=mode)
    torch.testing.assert_close(got, ref.reshape(3, g, g, -1), atol=1e-5, rtol=1e-5)
    assert not torch.allclose(got, with_residual.reshape(got.shape), atol=1e-3)
    assert not torch.allclose(got, clip.dense_features(images), atol=1e-3)


def test_attention_maps_have_the_token_shape_and_rows_sum_to_one(clip, images):
    from abm.grounding.clip import last_block_attention

    x, last, _ = _last_block_input(clip, images)
    g = clip.grid_size
    with torch.no_grad():
        h = last.layer_norm1(x)
        for mode, total in (("clearclip", 1.0), ("sclip", 2.0), ("naclip", 1.0)):
            att = last_block_attention(last.self_attn, h, mode, (g, g))
            assert att.shape == (3, last.self_attn.num_heads, 1 + g * g, 1 + g * g)
            torch.testing.assert_close(att.sum(-1), torch.full(att.shape[:-1], total), atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="grid"):
        last_block_attention(last.self_attn, h, "naclip", (g + 1, g))
    with pytest.raises(ValueError, match="dense mode"):
        last_block_attention(last.self_attn, h, "segment-anything", (g, g))


def test_naclip_attention_is_local(clip):
    """With identical tokens only the Gaussian window differs: weights fall with grid distance, patches
    ignore the CLS token, and a patch's feature does not depend on a far patch much."""
    from abm.grounding.clip import gaussian_window, last_block_attention

    last = clip.model.vision_model.encoder.layers[-1]
    g = 12
    h = torch.randn(1, 1, 32).expand(1, 1 + g * g, 32).contiguous()
    with torch.no_grad():
        att = last_block_attention(last.self_attn, h, "naclip", (g, g), sigma=2.0)[0, 0]
    centre = 1 + 6 * g + 6
    row = att[centre, 1:].reshape(g, g)
    assert att[centre, 0] == 0
    assert row[6, 6] > row[6, 7] > row[6, 9] > row[6, 11]
    assert row[6, 7] == pytest.approx(row[7, 6].item())
    win = gaussian_window((g, g), 2.0)
    assert win.shape == (g * g, g * g) and win[0, 0] == 1 and win[0, g * g - 1] < 1e-10


def test_naclip_output_is_local_on_images(clip):
    """Changing the pixels in one corner changes NACLIP's features in the far corner less than ClearCLIP's
    (whose attention is global)."""
    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, size=(1, 64, 64, 3), dtype=np.uint8)
    b = a.copy()
    b[0, :16, :16] = 255 - b[0, :16, :16]
    far = (slice(None), slice(5, 8), slice(5, 8))
    change = {m: (clip.dense_features(a, mode=m)[far] - clip.dense_features(b, mode=m)[far]).norm(dim=-1).mean()
              for m in ("naclip", "clearclip")}
    assert change["naclip"] < change["clearclip"]
