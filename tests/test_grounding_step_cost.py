"""What makes a CLIP proposal grounding step cheap keeps its results: crop embeddings that do not depend on their
batch (so the grounder's crop memory is exact), the last layer at the CLS token only, per-patch similarities and
the base points' box filter (tiny random CLIP, synthetic scene)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import ClipGrounder
from abm.grounding.grounders import LiftedFeatures, candidate_crops, point_similarity
from abm.grounding.proposals import object_proposals, same_colour, with_base_points
from abm.render.synthetic import synthetic_scene


@pytest.fixture(scope="module")
def scene():
    """(observation, fused cloud, tiny random CLIP, the image crops of the scene's candidates)."""
    pytest.importorskip("transformers")
    from abm.grounding.clip import tiny_clip

    obs, _names = synthetic_scene(seed=0, resolution=64)
    cloud = fuse_cameras(obs, Workspace())
    grounder = ClipGrounder(backbone=tiny_clip(seed=0), mode="proposals")
    props = object_proposals(cloud.xyz, cloud.rgb, grounder.proposal_config)
    crops, _, _ = candidate_crops(obs, cloud, props.candidates, grounder.proposal_config)
    assert len(crops) >= 3
    return obs, cloud, grounder.backbone, crops


def test_crop_embeddings_are_the_full_forward_and_do_not_depend_on_the_batch(scene):
    from abm.grounding.clip import run_encoder_layer

    _obs, _cloud, backbone, crops = scene
    side = (backbone.image_size, backbone.image_size)
    batch = backbone.image_features(crops, side)
    alone = torch.cat([backbone.image_features([c], side) for c in crops])
    torch.testing.assert_close(batch, alone, rtol=0, atol=1e-6)
    vision = backbone.model.vision_model  # every layer at every token, then the CLS token (what it replaces)
    with torch.no_grad():
        x = vision.pre_layrnorm(vision.embeddings(backbone.preprocess(crops, side)))
        for layer in vision.encoder.layers:
            x = run_encoder_layer(layer, x)
        full = F.normalize(backbone.model.visual_projection(vision.post_layernorm(x[:, 0])), dim=-1)
    torch.testing.assert_close(batch, full, rtol=0, atol=1e-5)


def test_a_crop_met_again_is_not_encoded_again(scene):
    _obs, _cloud, backbone, crops = scene
    grounder = ClipGrounder(backbone=backbone, mode="proposals")
    first = grounder.crop_embeddings(crops[:2])
    assert grounder.backbone_calls == 2
    again = grounder.crop_embeddings([crops[1], crops[2], crops[1].copy()])  # one new crop, two met before
    assert grounder.backbone_calls == 3
    np.testing.assert_allclose(again[0], first[1], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(again[0], again[2])
    fresh = ClipGrounder(backbone=backbone, mode="proposals").crop_embeddings(crops[:3])
    np.testing.assert_allclose(again[:2], fresh[1:3], rtol=0, atol=1e-6)


def test_per_patch_similarity_is_the_per_point_one(scene):
    obs, cloud, backbone, _crops = scene
    grounder = ClipGrounder(backbone=backbone, mode="proposals")
    lifted = grounder.lifted_features(obs, cloud)
    assert isinstance(lifted, LiftedFeatures) and len(lifted) == len(cloud)
    feats = grounder.point_features(obs, cloud)
    np.testing.assert_array_equal(lifted[np.arange(len(cloud))], feats)
    compact = lifted.compact()  # what a grounding cache stores: the rows some point uses
    assert len(compact.table) == len(np.unique(lifted.index)) < len(lifted.table)
    np.testing.assert_array_equal(compact.dense(), feats)
    np.testing.assert_array_equal(LiftedFeatures.per_point(feats).dense(), feats)
    text = grounder.text_features(["a photo of a block"]).astype(np.float64)[0]
    expected = (feats @ text).astype(np.float32)
    np.testing.assert_allclose(point_similarity(lifted, text), expected, rtol=0, atol=1e-7)
    np.testing.assert_allclose(point_similarity(feats, text), expected, rtol=0, atol=1e-7)


def test_base_points_of_a_candidate_are_those_within_a_voxel(scene):
    _obs, cloud, _backbone, _crops = scene
    props = object_proposals(cloud.xyz, cloud.rgb)
    xyz, rgb = np.asarray(cloud.xyz, np.float64), np.asarray(cloud.rgb, np.float64)
    for members in props.candidates:
        got = with_base_points(xyz, rgb, members, props.table, 0.01, 0.05)
        low = np.nonzero(props.table)[0]  # brute force: every table point's distance to the members
        dist = np.sqrt(((xyz[low, None] - xyz[None, members]) ** 2).sum(-1))
        near = dist.min(1) < 0.01
        nearest = members[dist.argmin(1)]
        same = near & same_colour(rgb[low], rgb[nearest], 0.05)
        np.testing.assert_array_equal(got, np.union1d(members, low[same]))


def test_the_lean_attention_is_the_modules(scene):
    from abm.grounding.clip import sdpa_attention

    _obs, _cloud, backbone, crops = scene
    layer = backbone.model.vision_model.encoder.layers[0]
    side = (backbone.image_size, backbone.image_size)
    with torch.no_grad():
        h = layer.layer_norm1(backbone.model.vision_model.embeddings(backbone.preprocess(crops[:2], side)))
        own = layer.self_attn(hidden_states=h)
        lean = sdpa_attention(layer.self_attn, h)
    assert isinstance(lean, torch.Tensor)  # the module's sdpa implementation without gradients: the lean path
    torch.testing.assert_close(lean, own[0], rtol=0, atol=1e-6)
    assert isinstance(sdpa_attention(layer.self_attn, h), tuple)  # recording gradients: the module itself
