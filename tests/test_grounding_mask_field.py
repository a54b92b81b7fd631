"""Object Mask Field: normalisations, threshold, fallback, rendering into the virtual views."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abm.geometry import PointCloud, Workspace
from abm.grounding.mask_field import (
    MaskField,
    MaskFieldConfig,
    mask_field_from_features,
    mask_views,
    normalize_heatmap,
    threshold_heatmap,
)
from abm.render import OrthographicRenderer

SIM = np.array([0.10, 0.20, 0.25, 0.30, 0.18], np.float32)


def test_raw_keeps_cosines():
    np.testing.assert_allclose(normalize_heatmap(SIM, "raw"), SIM)


def test_minmax():
    heat = normalize_heatmap(SIM, "minmax")
    np.testing.assert_allclose(heat, [0.0, 0.5, 0.75, 1.0, 0.4], atol=1e-6)
    assert np.all(normalize_heatmap(np.full(4, 0.3), "minmax") == 0.0)  # constant input: nothing stands out


def test_softmax_against_negatives():
    neg = np.array([[0.2, 0.1], [0.2, 0.1], [0.2, 0.1], [0.2, 0.1], [0.2, 0.1]], np.float32)
    heat = normalize_heatmap(SIM, "softmax", neg, logit_scale=100.0)
    logits = 100.0 * np.concatenate([SIM[:, None], neg], 1)
    expected = np.exp(logits[:, 0]) / np.exp(logits).sum(1)
    np.testing.assert_allclose(heat, expected, rtol=1e-5)
    assert heat[3] > 0.99 and heat[0] < 0.01
    # a higher temperature (smaller scale) flattens the distribution
    flat = normalize_heatmap(SIM, "softmax", neg, logit_scale=1.0)
    assert flat.max() < 0.4
    with pytest.raises(ValueError, match="negative"):
        normalize_heatmap(SIM, "softmax")
    with pytest.raises(ValueError, match="normalization"):
        normalize_heatmap(SIM, "zscore")


def test_threshold_and_found():
    mask, found = threshold_heatmap(np.array([0.1, 0.7, 0.9, 0.69]), 0.7)
    np.testing.assert_array_equal(mask, [0, 1, 1, 0])
    assert found and mask.dtype == np.float32


def test_empty_mask_fallback():
    heat = np.array([0.1, 0.5, 0.3, 0.45], np.float32)
    mask, found = threshold_heatmap(heat, 0.7, fallback="top", fallback_top_k=1)
    np.testing.assert_array_equal(mask, [0, 1, 0, 0])
    assert not found
    mask, _ = threshold_heatmap(heat, 0.7, fallback="top", fallback_top_k=2)
    np.testing.assert_array_equal(mask, [0, 1, 0, 1])
    mask, found = threshold_heatmap(heat, 0.7, fallback="none")
    assert not mask.any() and not found
    mask, found = threshold_heatmap(np.zeros(0, np.float32), 0.7)
    assert mask.shape == (0,) and not found


def test_mask_field_from_features():
    feats = np.eye(3, dtype=np.float32)[[0, 1, 2, 0]]  # points 0 and 3 look like "target" (axis 0)
    text = np.array([1.0, 0.0, 0.0], np.float32)
    negatives = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], np.float32)
    field = mask_field_from_features(feats, text, negatives, MaskFieldConfig("softmax"), "cup", "a photo of a cup")
    np.testing.assert_array_equal(field.mask, [1, 0, 0, 1])
    assert field.found and field.target == "cup"
    np.testing.assert_allclose(field.similarity, [1, 0, 0, 1])
    raw = mask_field_from_features(feats * 0.5, text, None, MaskFieldConfig("raw"))
    assert not raw.found and raw.mask.sum() == 1  # cosine 0.5 < 0.7: fallback keeps the best point
    with pytest.raises(ValueError, match="disagree"):
        mask_field_from_features(feats, np.ones(4), None, MaskFieldConfig("raw"))


def test_config_validation():
    with pytest.raises(ValueError):
        MaskFieldConfig(normalization="sigmoid")
    with pytest.raises(ValueError):
        MaskFieldConfig(fallback="random")
    with pytest.raises(ValueError):
        MaskFieldConfig(negatives=())
    assert MaskFieldConfig().key() != MaskFieldConfig(threshold=0.5).key()


def test_mask_field_center_and_shapes():
    field = MaskField(np.array([0, 1, 1, 0]), np.array([0.1, 0.9, 0.8, 0.2]), True)
    xyz = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], np.float32)
    np.testing.assert_allclose(field.center(xyz), [0.5, 0.5, 0])
    assert MaskField(np.zeros(3), np.zeros(3), False).center(xyz[:3]) is None
    with pytest.raises(ValueError):
        MaskField(np.zeros(3), np.zeros(4), True)


def _blob_cloud():
    rng = np.random.default_rng(0)
    table = np.stack([rng.uniform(0.1, 0.9, 3000), rng.uniform(-0.4, 0.4, 3000), np.zeros(3000)], 1)
    cube = rng.uniform([0.55, 0.15, 0.0], [0.61, 0.21, 0.06], size=(800, 3))
    xyz = np.concatenate([table, cube]).astype(np.float32)
    n = len(xyz)
    cloud = PointCloud(xyz, np.full((n, 3), 0.5, np.float32), np.zeros(n, np.int64), np.zeros((n, 2), np.int64),
                       ["cam"])
    mask = np.r_[np.zeros(3000), np.ones(800)].astype(np.float32)
    return cloud, mask


def test_mask_views_center_pixel_on_the_object():
    cloud, mask = _blob_cloud()
    renderer = OrthographicRenderer(Workspace(), resolution=64)
    views = mask_views(renderer, cloud, mask)
    assert views.center.shape == views.soft.shape == views.full.shape == (5, 64, 64)
    assert torch.all(views.center.sum((1, 2)) == 1)  # exactly one pixel per view
    assert torch.all((views.center * views.full).sum((1, 2)) == 1)  # ... and it lies on the mask
    # the marked pixel back-projects near the cube centre (within a pixel + the cube's half size)
    uv, _ = renderer.project(torch.tensor([[0.58, 0.18, 0.03]]))
    for v in range(5):
        r, c = np.argwhere(views.center[v].numpy())[0]
        assert abs(c - uv[0, v, 0]) <= 3 and abs(r - uv[0, v, 1]) <= 3
    assert set(views.as_dict()) == {"center", "soft", "full"}
    empty = mask_views(renderer, cloud, np.zeros(len(cloud), np.float32))
    assert empty.center.sum() == 0
    with pytest.raises(ValueError, match="points"):
        mask_views(renderer, cloud, np.zeros(3))
