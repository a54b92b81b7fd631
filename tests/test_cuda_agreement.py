"""CUDA and CPU agree (run where CUDA exists, skipped elsewhere): the renderer's views are equal and the
policy's fp32 forward pass matches within 1e-4."""

from __future__ import annotations

import copy

import pytest
import torch

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def _batch():
    from abm.data.keyframes import KeyframeDataset, collate
    from abm.geometry import Workspace
    from abm.train.synthetic import synthetic_episodes

    episodes = synthetic_episodes(1, camera_resolution=48)
    return collate([KeyframeDataset(episodes, Workspace(), mask=True, augment=False)[i] for i in range(2)])


def test_renderer_views_are_equal() -> None:
    from abm.geometry import Workspace
    from abm.render import OrthographicRenderer

    batch = _batch()
    views = {}
    for device in ("cpu", "cuda"):
        renderer = OrthographicRenderer(Workspace(), 64, device=device)
        out = renderer.render(batch["points"], batch["colors"], valid=batch["valid"])
        views[device] = out.rvt_channels().cpu()
    torch.testing.assert_close(views["cuda"], views["cpu"], atol=1e-5, rtol=0)


def test_policy_forward_matches_in_fp32() -> None:
    from abm.policy import KeyframePolicy, PolicyConfig
    from abm.policy.language import HashLanguageEncoder

    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "abm", resolution=48, lang_dim=32)
    cpu = KeyframePolicy(cfg, HashLanguageEncoder(32)).eval()
    gpu = copy.deepcopy(cpu).to("cuda")
    batch = _batch()
    with torch.no_grad():
        ref = cpu.model(**{k: v for k, v in cpu.model_inputs(batch).items()})
        inputs = gpu.model_inputs(batch)
        got = gpu.model(**inputs)  # fp32: run_model would use bf16 autocast on CUDA
    for name in ("heatmap", "rotation", "gripper", "collision"):
        torch.testing.assert_close(getattr(got, name).cpu(), getattr(ref, name), atol=1e-4, rtol=1e-4, msg=name)
