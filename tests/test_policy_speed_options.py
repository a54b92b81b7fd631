"""The training speed options of the policy: ``torch.compile`` of the network and bf16 autocast on CPU."""

from __future__ import annotations

import pytest
import torch

from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.language import HashLanguageEncoder


def _policy() -> KeyframePolicy:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "abm", resolution=16, patch_size=8, lang_dim=16)
    return KeyframePolicy(cfg, HashLanguageEncoder(16)).eval()


def _inputs(policy: KeyframePolicy) -> dict[str, torch.Tensor]:
    cfg = policy.config
    r, v = cfg.resolution, cfg.num_views
    gen = torch.Generator().manual_seed(1)
    mask = torch.zeros(2, v, 1, r, r)
    mask[:, :, 0, r // 2, r // 2] = 1.0
    return {"images": torch.randn(2, v, 10, r, r, generator=gen), "proprio": torch.rand(2, 4, generator=gen),
            "lang": torch.randn(2, cfg.lang_tokens, cfg.lang_dim, generator=gen), "mask": mask}


def test_compiled_network_gives_the_eager_output_and_keeps_checkpoint_keys(tmp_path) -> None:
    policy = _policy()
    inputs = _inputs(policy)
    keys = list(policy.state_dict())
    with torch.no_grad():
        eager = policy.run_model(inputs).heatmap
        # the graph capture is what this checks; the "eager" backend skips the ~50 s Inductor code generation
        compiled = policy.compile_network(backend="eager").run_model(inputs).heatmap
    assert policy.__dict__["_compiled_model"] is not None
    assert torch.allclose(eager, compiled, atol=1e-6)
    assert list(policy.state_dict()) == keys  # no "_orig_mod." entries: checkpoints stay loadable
    loaded = KeyframePolicy.from_checkpoint(policy.save(tmp_path / "c.pt"))
    with torch.no_grad():
        assert torch.allclose(loaded.run_model(inputs).heatmap, eager, atol=1e-6)
    policy.compile_network(False)
    assert policy.__dict__["_compiled_model"] is None


def test_cpu_bf16_follows_the_mode() -> None:
    policy = _policy()
    assert policy.use_cpu_bf16("auto") is False  # float32 on the CPU: measured faster (docs/performance.md)
    assert policy.use_cpu_bf16("off") is False
    inputs = _inputs(policy)
    with torch.no_grad():
        full = policy.run_model(inputs).heatmap
        assert policy.use_cpu_bf16("on") is True
        half = policy.run_model(inputs).heatmap
    # autocast really ran: the output differs from float32 by bf16 rounding, yet stays close
    assert not torch.equal(full, half.float())
    assert torch.allclose(full, half.float(), atol=0.1, rtol=0.1)
    with pytest.raises(ValueError, match="'auto', 'on' or 'off'"):
        policy.use_cpu_bf16("yes")
