"""One CLIP model configuration shared by the CLIP grounder and the CLIP text encoder, and the places that ask
"does this use a CLIP?" through it (the zoo, evaluation's CLIP folders) instead of comparing kind names."""

from __future__ import annotations

import pytest
import torch

from abm import zoo
from abm.errors import ConfigError
from abm.evaluation.policies import clip_names
from abm.grounding.config import (
    ClipGrounderConfig,
    ClipModelConfig,
    OracleGrounderConfig,
    TrackingGrounderConfig,
    grounder_from_flags,
)
from abm.policy.language_config import (
    ClipLanguageConfig,
    HashLanguageConfig,
    build_language_encoder,
    default_language,
    language_config_from_dict,
)


def test_the_grounder_and_the_text_encoder_name_one_clip_model() -> None:
    grounder = ClipGrounderConfig(model="m", device="cpu", threshold=0.3, mode="field")
    assert grounder.clip_model() == ClipModelConfig("m", "cpu")
    assert default_language(grounder) == ClipLanguageConfig(ClipModelConfig("m", "cpu"))  # its text tower
    assert TrackingGrounderConfig(inner=grounder).clip_model() == grounder.clip_model()  # tracking's inner CLIP
    assert OracleGrounderConfig().clip_model() is None and TrackingGrounderConfig().clip_model() is None
    assert default_language(OracleGrounderConfig()) == HashLanguageConfig()
    assert HashLanguageConfig().clip_model() is None
    assert grounder_from_flags("clip", "other").clip_model() == ClipModelConfig("other")
    assert ClipLanguageConfig().with_clip("w", "cuda").clip_model() == ClipModelConfig("w", "cuda")
    assert grounder.clip_options() == {"model": "m", "device": "cpu"} == default_language(grounder).clip_options()


def test_a_clip_language_spec_holds_the_model_and_older_ones_load() -> None:
    assert ClipLanguageConfig(ClipModelConfig("m")).to_dict() == {"kind": "clip", "model": "m"}
    assert ClipLanguageConfig(ClipModelConfig(allow_download=True)).to_dict() == {"kind": "clip",
                                                                                  "allow_download": True}
    older = {"kind": "clip", "model": "tiny", "device": "cpu", "mode": "field", "threshold": 0.3,
             "proposals": {"scoring": "crop"}}  # what checkpoints held: a whole CLIP grounder's options
    config = language_config_from_dict(older)
    assert config == ClipLanguageConfig(ClipModelConfig("tiny", "cpu"))
    assert config.to_dict() == {"kind": "clip", "model": "tiny", "device": "cpu"}
    assert language_config_from_dict(config.to_dict()) == config
    with pytest.raises(ConfigError, match=r"'clip' language encoder takes .*unknown option\(s\) \['bogus'\]"):
        language_config_from_dict({"kind": "clip", "bogus": 1})


def test_the_text_encoder_gives_the_text_towers_tokens_once_per_text() -> None:
    pytest.importorskip("transformers")
    from abm.grounding.clip import tiny_clip

    encoder = build_language_encoder({"kind": "clip", "model": "tiny", "device": "cpu"})
    assert encoder.spec() == {"kind": "clip", "model": "tiny", "device": "cpu"}
    texts = ["put X in the plate", "close X"]
    tokens = encoder.encode(texts)
    backbone = tiny_clip(seed=0)
    with torch.no_grad():
        expected = backbone.text_tokens(texts)  # the texts the encoder had not seen, in one batch
    assert tokens.dtype == torch.float32 and tokens.shape == (2, 77, backbone.text_width)
    assert (encoder.tokens, encoder.dim) == (77, backbone.text_width)
    torch.testing.assert_close(tokens, expected)
    again = encoder.encode(["close X", "put X in the plate", "close X"])  # memoised: the same rows
    assert torch.equal(again, tokens[[1, 0, 1]])


def test_evaluation_finds_the_clips_a_checkpoint_names() -> None:
    tracked = {"grounder": {"kind": "tracking", "inner": {"kind": "clip", "model": "a"}},
               "language": {"kind": "clip", "model": "b"}}
    assert clip_names(tracked) == ["a", "b"]
    assert clip_names({"grounder": {"kind": "clip", "model": "a"}, "language": {"kind": "clip", "model": "a"}}) == ["a"]
    assert clip_names({"grounder": {"kind": "clip"}, "language": {"kind": "hash", "dim": 8}}) == []  # the default
    assert clip_names({"grounder": {"kind": "oracle"}, "language": None}) == []


def test_the_zoo_asks_the_configurations_whether_a_model_needs_clip() -> None:
    rvt = {"name": "rvt", "method": "rvt", "grounder": "none (CLIP text)", "grounder_spec": {"kind": "oracle"},
           "language": "clip"}
    abm_hash = {"name": "abm", "method": "abm", "grounder": "clip", "language": "hash",
                "grounder_spec": {"kind": "clip", "model": "models/benchmark-clip"}}
    oracle = {"name": "abm_oracle", "method": "abm", "grounder": "oracle", "grounder_spec": {"kind": "oracle"},
              "language": "hash"}
    assert [zoo.needs_clip(e) for e in (rvt, abm_hash, oracle)] == [True, True, False]
    assert [zoo.grounds_with_clip(e) for e in (rvt, abm_hash, oracle)] == [False, True, False]
    clip = {"name": "benchmark-clip"}
    assert zoo.pick([oracle, abm_hash, clip], "abm") is abm_hash  # a CLIP-grounded model first
    assert zoo.pick([oracle, abm_hash], "abm") is oracle  # without the benchmark CLIP: one that needs none
    assert zoo.pick([oracle, abm_hash, rvt], "rvt") is None
