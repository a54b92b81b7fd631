"""3-D object proposals (geometry on synthetic clouds) and the CLIP grounder's proposals mode (tiny model)."""

from __future__ import annotations

import numpy as np
import pytest

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import ClipGrounder, build_grounder
from abm.grounding.grounders import candidate_crops
from abm.grounding.proposals import (
    ProposalConfig,
    color_parts,
    estimate_table_height,
    object_proposals,
    voxel_clusters,
    with_base_points,
)
from abm.render.synthetic import synthetic_scene


def _box(lo, hi, colour, step=0.004):
    axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi, strict=True)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return pts, np.tile(np.asarray(colour, float), (len(pts), 1))


def _scene(*parts):
    xyz = np.concatenate([p[0] for p in parts])
    rgb = np.concatenate([p[1] for p in parts])
    return xyz, rgb


TABLE = _box((0.2, -0.3, 0.0), (0.8, 0.3, 0.0), (0.6, 0.45, 0.3), step=0.006)


def _as_set(indices):
    return frozenset(int(i) for i in indices)


def test_two_boxes_on_a_plane_are_two_clusters():
    red = _box((0.30, 0.00, 0.002), (0.34, 0.04, 0.04), (0.9, 0.1, 0.1))
    blue = _box((0.50, 0.10, 0.002), (0.56, 0.14, 0.06), (0.1, 0.1, 0.9))
    xyz, rgb = _scene(TABLE, red, blue)
    n_table, n_red = len(TABLE[0]), len(red[0])
    assert estimate_table_height(xyz[:, 2]) == pytest.approx(0.0, abs=0.003)
    props = object_proposals(xyz, rgb, ProposalConfig(split=True))
    clusters = [_as_set(c) for c, k in zip(props.candidates, props.kinds, strict=True) if k == "cluster"]
    above = lambda lo, hi: _as_set(i for i in range(lo, hi) if xyz[i, 2] > 0.006)  # noqa: E731
    assert set(clusters) == {above(n_table, n_table + n_red), above(n_table + n_red, len(xyz))}
    assert props.table[:n_table].all() and not props.table[n_table:][xyz[n_table:, 2] > 0.006].any()
    # single-coloured boxes are not split further
    assert props.kinds.count("part") == 0


def test_an_object_held_in_the_hand_is_its_own_candidate_without_the_hand():
    # a top-down gripper at (0.5, 0, 0.2) holding a 4 cm bottle across its closed fingers (opening 0.5 = 4 cm)
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # TCP +z points down, fingers close along y
    pose[:3, 3] = (0.5, 0.0, 0.2)
    bottle = _box((0.48, -0.018, 0.13), (0.52, 0.018, 0.26), (0.2, 0.5, 0.2))  # 3 cm below to 6 cm above TCP
    fingers = [_box((0.492, y0, 0.19), (0.508, y0 + 0.012, 0.235), (0.5, 0.5, 0.5)) for y0 in (-0.032, 0.02)]
    palm = _box((0.49, -0.1, 0.225), (0.51, 0.1, 0.27), (0.5, 0.5, 0.5))  # 2.5 to 7 cm behind the TCP
    arm = _box((0.48, -0.02, 0.27), (0.52, 0.02, 0.6), (0.9, 0.9, 0.9))  # the wrist and arm going up
    xyz, rgb = _scene(TABLE, bottle, *fingers, palm, arm)
    n0 = len(TABLE[0])
    bottle_ids = np.arange(n0, n0 + len(bottle[0]))
    merged = object_proposals(xyz, rgb, ProposalConfig(hand_filter=False), pose, 0.5)
    assert len(merged) == 1 and len(merged.candidates[0]) > 2 * len(bottle_ids)  # bottle + hand + arm
    props = object_proposals(xyz, rgb, ProposalConfig(), pose, 0.5)
    held = max(props.candidates, key=lambda c: len(np.intersect1d(c, bottle_ids)))
    robot = np.arange(n0 + len(bottle[0]), len(xyz))
    assert not np.intersect1d(held, robot).size  # no hand point
    # the bottle keeps every point in front of the palm (it reaches 6 cm behind the TCP, into the palm's depth)
    # and between the fingers' inner faces (3 mm inside the opening: the faces the fingers touch go with them)
    in_front = bottle_ids[(xyz[bottle_ids, 2] < 0.2 + 0.02) & (np.abs(xyz[bottle_ids, 1]) < 0.017)]
    assert np.isin(in_front, held).all() and np.isin(held, bottle_ids).all()
    assert object_proposals(xyz, rgb, ProposalConfig(), None).candidates[0].size == merged.candidates[0].size


def test_box_on_a_plate_is_split_from_its_support():
    plate = _box((0.40, -0.10, 0.008), (0.60, 0.10, 0.016), (0.95, 0.95, 0.95))
    box = _box((0.47, -0.02, 0.02), (0.52, 0.03, 0.07), (0.8, 0.2, 0.1))
    xyz, rgb = _scene(TABLE, plate, box)
    n0 = len(TABLE[0]) + len(plate[0])
    whole = object_proposals(xyz, rgb, ProposalConfig(split=False))
    assert len(whole) == 1  # the box touches the plate: one cluster
    props = object_proposals(xyz, rgb, ProposalConfig(split=True))
    sets = {_as_set(c): k for c, k in zip(props.candidates, props.kinds, strict=True)}
    box_set = _as_set(range(n0, len(xyz)))
    plate_set = _as_set(range(len(TABLE[0]), n0))
    assert box_set in sets and plate_set in sets and (box_set | plate_set) in sets
    assert sets[box_set | plate_set] == "cluster"


def test_a_multicoloured_object_on_a_plate_is_found_as_the_plate_removed():
    plate = _box((0.40, -0.10, 0.008), (0.60, 0.10, 0.016), (0.95, 0.95, 0.95))
    top = _box((0.47, -0.02, 0.044), (0.52, 0.03, 0.07), (0.1, 0.6, 0.1))
    bottom = _box((0.47, -0.02, 0.02), (0.52, 0.03, 0.04), (0.8, 0.2, 0.1))
    xyz, rgb = _scene(TABLE, plate, bottom, top)
    n0 = len(TABLE[0]) + len(plate[0])
    props = object_proposals(xyz, rgb, ProposalConfig(split=True))
    sets = {_as_set(c): k for c, k in zip(props.candidates, props.kinds, strict=True)}
    assert sets.get(_as_set(range(n0, len(xyz)))) == "without"


def test_clusters_and_colour_parts_primitives():
    xyz = np.array([[0, 0, 0], [0.009, 0, 0], [0.05, 0, 0]], float)
    assert list(voxel_clusters(xyz, 0.01)) in ([0, 0, 1], [1, 1, 0])
    a, b = _box((0, 0, 0), (0.016, 0.016, 0.016), (1, 0, 0)), _box((0.02, 0, 0), (0.036, 0.016, 0.016), (0, 0, 1))
    pts, cols = _scene(a, b)
    parts = color_parts(pts, cols, 0.01, 0.1)
    assert len(set(parts[: len(a[0])])) == 1 and len(set(parts[len(a[0]):])) == 1 and parts[0] != parts[-1]
    assert len(set(color_parts(pts, cols, 0.01, 1.0))) == 1
    assert len(object_proposals(np.zeros((0, 3)), np.zeros((0, 3)))) == 0


def test_base_points_join_only_with_the_objects_colour():
    red = _box((0.30, 0.00, 0.0), (0.34, 0.04, 0.04), (0.9, 0.1, 0.1))
    xyz, rgb = _scene(TABLE, red)
    props = object_proposals(xyz, rgb, ProposalConfig(split=False))
    (members,) = props.candidates
    grown = with_base_points(xyz, rgb, members, props.table, 0.01, 0.12)
    added = np.setdiff1d(grown, members)
    assert len(added) > 0 and (xyz[added, 2] <= 0.006).all() and np.allclose(rgb[added], (0.9, 0.1, 0.1))


def test_config_validation_and_key():
    with pytest.raises(ValueError, match="scoring"):
        ProposalConfig(scoring="vote")
    assert ProposalConfig().key() != ProposalConfig(scoring="dense").key()


# ---- the grounder ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def setup():
    """(observation, object names, fused cloud, tiny random CLIP) of the synthetic scene."""
    pytest.importorskip("transformers")
    from abm.grounding.clip import tiny_clip

    obs, names = synthetic_scene(seed=0, resolution=64)
    return obs, names, fuse_cameras(obs, Workspace()), tiny_clip(seed=0)


@pytest.mark.parametrize("scoring", ["dense", "crop", "combined"])
def test_proposal_grounder_keeps_the_mask_field_contract(setup, scoring):
    obs, names, cloud, backbone = setup
    grounder = build_grounder({"kind": "clip", "mode": "proposals", "scoring": scoring}, backbone=backbone)
    assert grounder.proposal_config.scoring == scoring
    target = next(iter(names.values()))
    field = grounder.ground(obs, cloud, target, names)
    assert field.mask.shape == field.heatmap.shape == (len(cloud),) and field.mask.dtype == np.float32
    assert set(np.unique(field.mask)) <= {0.0, 1.0} and field.mask.sum() > 0
    assert 0.0 <= field.heatmap.min() and field.heatmap.max() <= 1.0 + 1e-6
    assert isinstance(field.found, bool) and field.center(cloud.xyz) is not None
    # the mask is one whole candidate (plus its base points), and it has the highest heatmap
    props = object_proposals(cloud.xyz, cloud.rgb, grounder.proposal_config)
    sel = np.nonzero(field.mask)[0]
    assert any(np.isin(c, sel).all() for c in props.candidates)
    assert field.heatmap[sel].max() == pytest.approx(field.heatmap.max())
    assert (field.similarity is None) == (scoring == "crop")


def test_proposal_options_enter_the_cache_key(setup):
    obs, names, cloud, backbone = setup
    target = next(iter(names.values()))
    shared = ClipGrounder(backbone=backbone)
    cache = shared.cache
    fields = {}
    for opts in ({"mode": "field"}, {"mode": "proposals"}, {"mode": "proposals", "proposals": {"scoring": "dense"}},
                 {"mode": "field", "dense_mode": "naclip"}):
        g = ClipGrounder(backbone=backbone, cache=cache, **opts)
        before = len(cache._memory) if hasattr(cache, "_memory") else None
        fields[str(opts)] = g.ground(obs, cloud, target, names)
        if before is not None:
            assert len(cache._memory) > before, f"{opts} reused another configuration's cache entry"
    assert not np.array_equal(fields["{'mode': 'field'}"].heatmap, fields["{'mode': 'proposals'}"].heatmap)


def test_candidate_crops_lie_inside_the_image(setup):
    obs, _names, cloud, _ = setup
    props = object_proposals(cloud.xyz, cloud.rgb)
    crops, owner, weight = candidate_crops(obs, cloud, props.candidates, ProposalConfig(crop_margin=2.4))
    assert crops and len(crops) == len(owner) == len(weight) and (weight >= 12).all()
    for crop in crops:
        assert crop.ndim == 3 and crop.shape[0] == crop.shape[1] >= 8


def test_unknown_modes_are_refused(setup):
    backbone = setup[3]
    with pytest.raises(ValueError, match="mode"):
        ClipGrounder(backbone=backbone, mode="sam")
    with pytest.raises(ValueError, match="dense_mode"):
        ClipGrounder(backbone=backbone, dense_mode="clearclip2")


def test_ground_command_takes_the_new_options(tmp_path):
    import json

    from abm.cli import main

    out = tmp_path / "g"
    assert main(["ground", "--out", str(out), "--grounder", "clip", "--clip-model", "tiny", "--resolution", "48",
                 "--mode", "proposals", "--scoring", "dense", "--dense-mode", "naclip", "--input-size", "96",
                 "--scales", "64"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["mode"], summary["scoring"], summary["dense_mode"], summary["input_size"]) == \
        ("proposals", "dense", "naclip", [96, 96])
    assert summary["mask_points"] > 0 and summary["scales"] == [64]


def test_resolved_spec_names_the_defaults_a_spec_relies_on(monkeypatch):
    from abm.grounding import config, grounders

    for name, value in (("DEFAULT_CLIP_MODE", "field"), ("DEFAULT_DENSE_MODE", "maskclip"),
                        ("DEFAULT_INPUT_SIZE", None), ("DEFAULT_SCALES", ())):
        monkeypatch.setattr(config, name, value)  # the defaults live with the typed configurations
    old = {"kind": "clip", "model": "m"}
    assert grounders.resolved_spec(old) == old  # the legacy defaults: cache keys of older specs stay valid
    assert grounders.resolved_spec({"kind": "oracle"}) == {"kind": "oracle"}
    assert grounders.resolved_spec({"kind": "tracking"}) == {"kind": "tracking"}  # no inner named: none added
    monkeypatch.setattr(config, "DEFAULT_CLIP_MODE", "proposals")
    monkeypatch.setattr(config, "DEFAULT_INPUT_SIZE", 256)
    got = grounders.resolved_spec(old)
    assert got["mode"] == "proposals" and got["input_size"] == 256 and "dense_mode" not in got
    assert got["proposals"] == ProposalConfig().__dict__
    explicit = grounders.resolved_spec({"kind": "clip", "mode": "field", "input_size": None})
    assert explicit == {"kind": "clip", "mode": "field", "input_size": None}
    tracked = grounders.resolved_spec({"kind": "tracking", "inner": {"kind": "clip", "scoring": "crop",
                                                                     "mode": "proposals"}})
    assert tracked["inner"]["proposals"]["scoring"] == "crop" and "scoring" not in tracked["inner"]


def test_multiscale_features_are_the_normalised_mean_of_each_scale(setup):
    obs, _names, cloud, backbone = setup
    single = ClipGrounder(backbone=backbone).point_features(obs, cloud)
    large = ClipGrounder(backbone=backbone, input_size=128).point_features(obs, cloud)
    multi = ClipGrounder(backbone=backbone, scales=[128])
    both = single + large
    np.testing.assert_allclose(multi.point_features(obs, cloud), both / np.linalg.norm(both, axis=1, keepdims=True),
                               atol=1e-5)
    assert multi.backbone_calls == 2 * len(cloud.camera_names)


def test_combined_scoring_crops_only_the_best_dense_candidates(setup):
    obs, names, cloud, backbone = setup
    target = next(iter(names.values()))
    cameras = len(cloud.camera_names)
    few = ClipGrounder(backbone=backbone, mode="proposals", proposals={"crop_top_k": 2, "crop_cameras": 2})
    few.ground(obs, cloud, target, names)
    assert cameras < few.backbone_calls <= cameras + 2 * 2
    every = ClipGrounder(backbone=backbone, mode="proposals", proposals={"crop_top_k": 0, "crop_cameras": 2})
    every.ground(obs, cloud, target, names)
    assert every.backbone_calls > few.backbone_calls
