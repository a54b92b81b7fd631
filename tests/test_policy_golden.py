"""Saved-output tests of the policy pipeline, to keep behaviour fixed through refactors.

A tiny ``abm`` policy with stored weights is run on two fixed synthetic keyframes (no augmentation):
the rendered views and mask, the model's outputs, the loss terms and the decoded actions must equal
the values saved in ``tests/data/golden_policy.npz``. Refactors of the data pipeline, the model or
the heads must keep these equal; an intended change regenerates the file with
``python tests/test_policy_golden.py --update`` and says why in the commit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from abm.data.keyframes import KeyframeDataset, collate
from abm.policy import KeyframePolicy, PolicyConfig, decode_output
from abm.policy.language import HashLanguageEncoder
from abm.train.synthetic import synthetic_episodes

GOLDEN = Path(__file__).parent / "data" / "golden_policy.npz"
TINY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
        "decoder_channels": 4, "lang_dim": 16}


def _compute(state: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset("small", "abm", **TINY)
    episodes = synthetic_episodes(1, camera_resolution=32)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim)).eval()
    if state is not None:
        policy.model.load_state_dict({k: torch.from_numpy(v) for k, v in state.items()})
    ds = KeyframeDataset(episodes, policy.workspace, **policy.sample_options(), augment=False)
    batch = collate([ds[0], ds[1]])
    with torch.no_grad():
        inputs = policy.model_inputs(batch)
        out = policy.run_model(inputs)
        _, terms = policy.compute_loss(batch)
        actions = policy.predict(batch)
    assert [a.position.tolist() for a in actions] == [a.position.tolist() for a in decode_output(out, policy.renderer)]
    result = {
        "images": inputs["images"].numpy(), "mask": inputs["mask"].numpy(), "heatmap": out.heatmap.numpy(),
        "rotation": out.rotation.numpy(), "gripper": out.gripper.numpy(),
        "loss": np.array([terms[k].item() for k in ("total", "translation", "rotation", "gripper", "collision")]),
        "positions": np.stack([a.position for a in actions]), "quaternions": np.stack([a.quaternion for a in actions]),
    }
    result.update({f"state/{k}": v.numpy() for k, v in policy.model.state_dict().items()})
    return result


def _stored() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as data:
        return dict(data)


def test_pipeline_matches_saved_outputs() -> None:
    stored = _stored()
    state = {k[len("state/"):]: v for k, v in stored.items() if k.startswith("state/")}
    got = _compute(state)
    for key in ("images", "mask", "heatmap", "rotation", "gripper", "loss", "positions"):
        np.testing.assert_allclose(got[key], stored[key], rtol=1e-4, atol=1e-5, err_msg=key)
    # quaternions: q and -q are the same rotation
    dots = np.abs(np.sum(got["quaternions"] * stored["quaternions"], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5)


if __name__ == "__main__":
    if "--update" not in sys.argv:
        sys.exit("usage: python tests/test_policy_golden.py --update   (rewrites tests/data/golden_policy.npz)")
    GOLDEN.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(GOLDEN, **_compute(None))
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size / 1024:.0f} KiB)")
