"""Saved-output tests of the policy pipeline, to keep behaviour fixed through refactors.

For every registered policy variant (:data:`abm.policy.variants.VARIANTS`) a tiny policy with stored
weights is run on two fixed synthetic keyframes (no augmentation): the rendered views, the mask or
CLIP-feature inputs, the model's outputs, the loss terms and the decoded actions must equal the values
saved in ``tests/data/golden_policy.npz`` (``abm``) and ``tests/data/golden_policy_<variant>.npz``
(the other variants). The test is parametrized over the registry, so a newly registered variant fails
until its file is written. Two two-stage cases (``abm+zoom``, ``ifd+zoom``: a zoomed second stage) are
saved the same way, with the zoomed stage's inputs and weights.

Each stage is compared on the stored output of the stage before it (:func:`_stagewise`), so the test does
not depend on the CPU's vector extensions: the network runs on the stored rendered views, the zoom centre is
decoded from the stored coarse heatmap, the zoomed views are rendered around the stored zoom centre and the
second network runs on the stored zoomed views, and the actions are decoded from the stored heatmaps and
bins. Chained end to end, a rounding difference of one ulp in the zoom centre (AVX-512 against AVX2 kernels)
moves points across a pixel border of the zoomed views and changes the second stage's heatmap by ~3e-4;
stage by stage every value stays within ``rtol=1e-4, atol=1e-5`` under the default, AVX2 and AVX-512
kernels, and :func:`test_a_small_change_of_one_weight_fails_the_comparison` shows the tolerances still
catch a change of the function. ``scripts/test.sh`` runs this file a second time with the AVX-512 kernels
switched off (docs/reliability.md).

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
from abm.policy.heads import decode_translation
from abm.policy.language import HashLanguageEncoder
from abm.policy.mvt import PolicyOutput
from abm.policy.variants import VARIANTS
from abm.samples import Batch
from abm.train.synthetic import synthetic_episodes

DATA = Path(__file__).parent / "data"
TINY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
        "decoder_channels": 4, "lang_dim": 16}
FEATURES = 8  # ifd_feature_dim of the tiny policies
ZOOM = {"zoom_size": 0.3, "zoom_resolution": 16, "zoom_patch_size": 4}  # the two-stage cases' zoomed stage
INPUTS = ("images", "mask", "ifd_features", "ifd_index")
COMPARED = (*INPUTS, "heatmap", "rotation", "gripper", "loss", "positions",
            "zoom_images", "zoom_mask", "zoom_center", "coarse_heatmap")
CASES = [*sorted(VARIANTS), "abm+zoom", "ifd+zoom"]
RTOL, ATOL = 1e-4, 1e-5
"""Tolerance of every compared value. Stage by stage the largest difference seen is 2 % of it (3e-7 absolute) with the
default, AVX2 and AVX-512 kernels; a weight of the heatmap decoder moved by 1e-3 exceeds it 3-4 times."""


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


def _policy_and_batch(case: str, state: dict[str, np.ndarray] | None) -> tuple[KeyframePolicy, Batch]:
    """The tiny policy of ``case`` (seeded weights, or ``state``: ``model/...`` and ``zoom_model/...`` arrays)
    and its batch of two synthetic keyframes."""
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
            s["feature_table"] = _point_features(s["points"], s["colors"])  # one row per point
            s["feature_row"] = torch.arange(len(s["points"]))
        if "point_heatmap" in s:  # the oracle's heatmap equals its binary mask: make it soft
            s["point_heatmap"] = _soft_heatmap(s["point_mask"], s["colors"])
    return policy, collate(samples)


def _outputs(out: PolicyOutput, policy: KeyframePolicy) -> dict[str, np.ndarray]:
    """The compared outputs of a network output: the heatmap, bins and decoded actions."""
    actions = decode_output(out, policy.renderer, policy.zoom_renderer)
    return {"heatmap": out.heatmap.numpy(), "rotation": out.rotation.numpy(), "gripper": out.gripper.numpy(),
            "positions": np.stack([a.position for a in actions]),
            "quaternions": np.stack([a.quaternion for a in actions])}


def _loss(policy: KeyframePolicy, batch: Batch) -> np.ndarray:
    """The loss terms (teacher-forced: a two-stage policy zooms on the label, no argmax in the chain)."""
    _, terms = policy.compute_loss(batch)
    names: tuple[str, ...] = ("total", "translation", "rotation", "gripper", "collision")
    names += ("zoom_translation",) if policy.zoom_model is not None else ()
    return np.array([terms[k].item() for k in names])


def _compute(case: str, state: dict[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """Every saved value of ``case``, computed end to end (what ``--update`` stores): the inputs, the outputs of
    :meth:`KeyframePolicy.infer` (the zoom centre decoded from the computed coarse heatmap), the loss terms, the
    decoded actions and the weights (``state/...``, ``zoom_state/...``)."""
    policy, batch = _policy_and_batch(case, state)
    with torch.no_grad():
        inputs = policy.model_inputs(batch)
        out, zoom_inputs = policy.infer(batch, inputs)
        result = {key: inputs[key].numpy() for key in INPUTS if key in inputs}
        result.update(_outputs(out, policy), loss=_loss(policy, batch))
        assert [a.position.tolist() for a in policy.predict(batch)] == result["positions"].tolist()
    result.update({f"state/{k}": v.numpy() for k, v in policy.model.state_dict().items()})
    if zoom_inputs is not None:
        assert out.zoom_center is not None and out.coarse_heatmap is not None and policy.zoom_model is not None
        result.update({"zoom_images": zoom_inputs["images"].numpy(), "zoom_center": out.zoom_center.numpy(),
                       "coarse_heatmap": out.coarse_heatmap.numpy()})
        if "mask" in zoom_inputs:
            result["zoom_mask"] = zoom_inputs["mask"].numpy()
        result.update({f"zoom_state/{k}": v.numpy() for k, v in policy.zoom_model.state_dict().items()})
    return result


def _stored_state(stored: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The stored weights, keyed ``model/...`` and ``zoom_model/...`` (as :func:`_policy_and_batch` takes them)."""
    return {("model/" + k[len("state/"):] if k.startswith("state/") else "zoom_model/" + k[len("zoom_state/"):]): v
            for k, v in stored.items() if k.startswith(("state/", "zoom_state/"))}


def _stagewise(case: str, stored: dict[str, np.ndarray], state: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The compared values of ``case`` with each stage fed the stored output of the stage before it.

    The views are rendered from the batch; the first network runs on the stored views (mask, CLIP features);
    the zoom centre is decoded from the stored coarse heatmap; the zoomed views are rendered around the stored
    zoom centre and the second network runs on the stored zoomed views; the actions are decoded from the stored
    heatmap and bins (around the stored zoom centre). No argmax of a recomputed value decides what a later stage
    sees, so a rounding difference between CPU kernels stays a rounding difference.
    """
    policy, batch = _policy_and_batch(case, state)

    def fed(inputs: dict[str, torch.Tensor], keys: dict[str, str]) -> dict[str, torch.Tensor]:
        return {**inputs, **{k: torch.from_numpy(stored[s]) for k, s in keys.items() if k in inputs}}

    def tensor(key: str) -> torch.Tensor:
        return torch.from_numpy(stored[key])

    with torch.no_grad():
        inputs = policy.model_inputs(batch)
        got = {key: inputs[key].numpy() for key in INPUTS if key in inputs}
        first = policy.run_model(fed(inputs, {k: k for k in INPUTS}))
        got["loss"] = _loss(policy, batch)
        if policy.zoom_model is None:
            out = first
            saved = PolicyOutput(tensor("heatmap"), tensor("rotation"), tensor("gripper"), first.collision)
        else:
            got["coarse_heatmap"] = first.heatmap.numpy()
            got["zoom_center"] = decode_translation(tensor("coarse_heatmap"), policy.renderer).numpy()
            center = tensor("zoom_center")
            zoom_inputs = policy.model_inputs(batch, zoom_center=center)
            got["zoom_images"] = zoom_inputs["images"].numpy()
            if "mask" in zoom_inputs:
                got["zoom_mask"] = zoom_inputs["mask"].numpy()
            fine = policy.run_model(fed(zoom_inputs, {"images": "zoom_images", "mask": "zoom_mask"}), zoom=True)
            out = PolicyOutput(fine.heatmap, fine.rotation, fine.gripper, fine.collision, zoom_center=center)
            saved = PolicyOutput(tensor("heatmap"), tensor("rotation"), tensor("gripper"), fine.collision,
                                 zoom_center=center)
    got.update({k: v for k, v in _outputs(out, policy).items() if k in ("heatmap", "rotation", "gripper")})
    got.update({k: v for k, v in _outputs(saved, policy).items() if k in ("positions", "quaternions")})
    return got


def _stored(variant: str) -> dict[str, np.ndarray]:
    path = golden_file(variant)
    if not path.exists():
        pytest.fail(f"no saved outputs for policy variant {variant!r} ({path}); write them with "
                    f"`PYTHONPATH=src python tests/test_policy_golden.py --update {variant}`")
    with np.load(path) as data:
        return dict(data)


def _mismatches(got: dict[str, np.ndarray], stored: dict[str, np.ndarray]) -> list[str]:
    """The compared keys whose values differ beyond the tolerance (quaternions up to sign: q and -q are the
    same rotation), each with its largest difference."""
    assert {k for k in got if k in COMPARED} == {k for k in stored if k in COMPARED}  # same inputs per variant
    bad = [f"{key}: max |difference| {np.max(np.abs(got[key] - stored[key])):.3g}" for key in COMPARED
           if key in stored and not np.allclose(got[key], stored[key], rtol=RTOL, atol=ATOL)]
    dots = np.abs(np.sum(got["quaternions"] * stored["quaternions"], axis=-1))
    if not np.allclose(dots, 1.0, atol=ATOL):
        bad.append(f"quaternions: |q . q_saved| {dots.tolist()}")
    return bad


@pytest.mark.parametrize("variant", CASES)
def test_pipeline_matches_saved_outputs(variant: str) -> None:
    stored = _stored(variant)
    assert _mismatches(_stagewise(variant, stored, _stored_state(stored)), stored) == [], variant


@pytest.mark.parametrize("case", ["abm", "ifd+zoom"])
def test_a_small_change_of_one_weight_fails_the_comparison(case: str) -> None:
    """The tolerances are tight enough to see a change of the function: one weight of the last stage's heatmap
    decoder moved by 1e-3 (its values are ~0.3) fails the comparison of that stage's heatmap."""
    stored = _stored(case)
    state = _stored_state(stored)
    net = "zoom_model" if "+" in case else "model"
    last = max(k for k in state if k.startswith(f"{net}/decode.") and k.endswith(".weight"))
    changed = {**state, last: state[last].copy()}
    changed[last].flat[0] += 1e-3
    bad = _mismatches(_stagewise(case, stored, changed), stored)
    assert any(b.startswith("heatmap:") for b in bad), bad


def test_the_zoom_stage_follows_the_coarse_stage() -> None:
    """End to end (no saved values, so independent of the CPU): ``infer`` zooms on the point decoded from its own
    coarse heatmap and ``predict`` decodes the zoomed heatmap around it."""
    policy, batch = _policy_and_batch("ifd+zoom", None)
    out, _ = policy.infer(batch)
    assert out.zoom_center is not None and out.coarse_heatmap is not None
    assert torch.equal(out.zoom_center, decode_translation(out.coarse_heatmap, policy.renderer))
    assert [a.position.tolist() for a in policy.predict(batch)] == [
        a.position.tolist() for a in decode_output(out, policy.renderer, policy.zoom_renderer)]


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
