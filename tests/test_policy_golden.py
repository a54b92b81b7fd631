"""Saved-output tests of the policy pipeline, to keep behaviour fixed through refactors.

For every registered policy variant (:data:`abm.policy.variants.VARIANTS`) a tiny policy with stored
weights is run on two fixed synthetic keyframes (no augmentation): the rendered views, the mask or
CLIP-feature inputs, the model's outputs, the loss terms and the decoded actions must equal the values
saved in ``tests/data/golden_policy.npz`` (``abm``) and ``tests/data/golden_policy_<variant>.npz``
(the other variants). The test is parametrized over the registry, so a newly registered variant fails
until its file is written. Two two-stage cases (``abm+zoom``, ``ifd+zoom``: a zoomed second stage) are
saved the same way, with the zoomed stage's inputs and weights.

Refactors of the data pipeline, the model or the heads must keep these equal; an intended change (or a
new variant) regenerates the files -- never done by the test itself -- with::

    PYTHONPATH=src python tests/test_policy_golden.py --update              # every variant
    PYTHONPATH=src python tests/test_policy_golden.py --update ifd abm+zoom # only these

and says why in the commit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from abm.data.keyframes import KeyframeDataset, collate
from abm.policy import KeyframePolicy, PolicyConfig, decode_output
from abm.policy.language import HashLanguageEncoder
from abm.policy.variants import VARIANTS
from abm.train.synthetic import synthetic_episodes

DATA = Path(__file__).parent / "data"
TINY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
        "decoder_channels": 4, "lang_dim": 16}
FEATURES = 8  # ifd_feature_dim of the tiny policies
ZOOM = {"zoom_size": 0.3, "zoom_resolution": 16, "zoom_patch_size": 4}  # the two-stage cases' zoomed stage
COMPARED = ("images", "mask", "ifd_features", "ifd_index", "heatmap", "rotation", "gripper", "loss", "positions",
            "zoom_images", "zoom_mask", "zoom_center", "coarse_heatmap")
CASES = [*sorted(VARIANTS), "abm+zoom", "ifd+zoom"]


def golden_file(case: str) -> Path:
    """Where the saved outputs of ``case`` (a variant, or ``VARIANT+zoom``) live (``abm`` keeps the original
    file name)."""
    return DATA / ("golden_policy.npz" if case == "abm" else f"golden_policy_{case}.npz")


def _point_features(points: torch.Tensor, colors: torch.Tensor) -> torch.Tensor:
    """Fixed stand-in for per-point CLIP features: a deterministic function of position and colour."""
    base = torch.cat([colors, points, colors * points[:, :1], points[:, 2:] - colors[:, :1]], -1)  # (N, 8)
    return base[:, :FEATURES].to(torch.float32)


def _soft_heatmap(mask: torch.Tensor, colors: torch.Tensor) -> torch.Tensor:
    """Fixed soft per-point heatmap (values in (0, 1) on and off the mask), so the soft-mask variant
    (``concat-rerendered``) sees other input than the binarised ones."""
    return (0.15 + 0.7 * mask.to(torch.float32) * (0.4 + 0.6 * colors[:, 1])).to(torch.float32)


def _compute(case: str, state: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    torch.manual_seed(0)
    variant, _, zoom = case.partition("+")
    extra = {"ifd_feature_dim": FEATURES} if VARIANTS[variant].clip_features else {}
    cfg = PolicyConfig.from_preset("small", variant, **TINY, **extra, **(ZOOM if zoom else {}))
    episodes = synthetic_episodes(1, camera_resolution=32)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim)).eval()
    if state is not None:
        policy.load_networks({net: {k[len(net) + 1:]: torch.from_numpy(v) for k, v in state.items()
                                    if k.startswith(net + "/")} for net in ("model", "zoom_model")})
    options = policy.sample_options()
    features = options.pop("features")  # the stand-in features below replace a grounder's cache
    ds = KeyframeDataset(episodes, policy.workspace, **options, augment=False)
    samples = [ds[0], ds[1]]
    for s in samples:
        if features:
            s["point_features"] = _point_features(s["points"], s["colors"])
        if "point_heatmap" in s:  # the oracle's heatmap equals its binary mask: make it soft
            s["point_heatmap"] = _soft_heatmap(s["point_mask"], s["colors"])
    batch = collate(samples)
    with torch.no_grad():
        inputs = policy.model_inputs(batch)
        out, zoom_inputs = policy.infer(batch, inputs)
        _, terms = policy.compute_loss(batch)
        actions = policy.predict(batch)
    decoded = decode_output(out, policy.renderer, policy.zoom_renderer)
    assert [a.position.tolist() for a in actions] == [a.position.tolist() for a in decoded]
    result = {key: inputs[key].numpy() for key in ("images", "mask", "ifd_features", "ifd_index") if key in inputs}
    result.update({
        "heatmap": out.heatmap.numpy(), "rotation": out.rotation.numpy(), "gripper": out.gripper.numpy(),
        "loss": np.array([terms[k].item() for k in ("total", "translation", "rotation", "gripper", "collision")]),
        "positions": np.stack([a.position for a in actions]), "quaternions": np.stack([a.quaternion for a in actions]),
    })
    result.update({f"state/{k}": v.numpy() for k, v in policy.model.state_dict().items()})
    if zoom_inputs is not None:
        assert out.zoom_center is not None and out.coarse_heatmap is not None and policy.zoom_model is not None
        result.update({"zoom_images": zoom_inputs["images"].numpy(), "zoom_center": out.zoom_center.numpy(),
                       "coarse_heatmap": out.coarse_heatmap.numpy(),
                       "loss": np.append(result["loss"], terms["zoom_translation"].item())})
        if "mask" in zoom_inputs:
            result["zoom_mask"] = zoom_inputs["mask"].numpy()
        result.update({f"zoom_state/{k}": v.numpy() for k, v in policy.zoom_model.state_dict().items()})
    return result


def _stored(variant: str) -> dict[str, np.ndarray]:
    path = golden_file(variant)
    if not path.exists():
        pytest.fail(f"no saved outputs for policy variant {variant!r} ({path}); write them with "
                    f"`PYTHONPATH=src python tests/test_policy_golden.py --update {variant}`")
    with np.load(path) as data:
        return dict(data)


@pytest.mark.parametrize("variant", CASES)
def test_pipeline_matches_saved_outputs(variant: str) -> None:
    stored = _stored(variant)
    state = {("model/" + k[len("state/"):] if k.startswith("state/") else "zoom_model/" + k[len("zoom_state/"):]): v
             for k, v in stored.items() if k.startswith(("state/", "zoom_state/"))}
    got = _compute(variant, state)
    assert {k for k in got if k in COMPARED} == {k for k in stored if k in COMPARED}  # same inputs per variant
    for key in COMPARED:
        if key in stored:
            np.testing.assert_allclose(got[key], stored[key], rtol=1e-4, atol=1e-5, err_msg=f"{variant}: {key}")
    # quaternions: q and -q are the same rotation
    dots = np.abs(np.sum(got["quaternions"] * stored["quaternions"], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5, err_msg=variant)


def test_every_saved_file_belongs_to_a_registered_variant() -> None:
    names = {p.name for p in DATA.glob("golden_policy*.npz")}
    assert names == {golden_file(v).name for v in CASES}


if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] != "--update":
        sys.exit("usage: PYTHONPATH=src python tests/test_policy_golden.py --update [VARIANT ...]   "
                 "(rewrites tests/data/golden_policy*.npz of the variants, default all)")
    chosen = sys.argv[2:] or CASES
    unknown = sorted(set(chosen) - set(CASES))
    if unknown:
        sys.exit(f"unknown cases {unknown}; known: {CASES}")
    DATA.mkdir(parents=True, exist_ok=True)
    for name in chosen:
        path = golden_file(name)
        np.savez_compressed(path, **_compute(name, None))
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
