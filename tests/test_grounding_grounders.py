"""Grounders (oracle, CLIP on the tiny model), the cache, the metric and the ``abm ground`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from abm.geometry import Workspace, fuse_cameras
from abm.grounding import (
    ClipGrounder,
    ClipGrounderConfig,
    GroundingCache,
    MaskField,
    OracleGrounder,
    build_grounder,
    match_object_ids,
    target_point_mask,
)
from abm.grounding.metrics import score_mask, summarize
from abm.render.synthetic import synthetic_scene
from abm.types import CameraFrame, Observation


@pytest.fixture(scope="module")
def scene():
    obs, names = synthetic_scene(seed=0, resolution=64)
    return obs, names, fuse_cameras(obs, Workspace())


@pytest.fixture(scope="module")
def backbone():
    pytest.importorskip("transformers")
    from abm.grounding.clip import tiny_clip

    return tiny_clip(seed=0)


def test_oracle_marks_exactly_the_target(scene):
    obs, names, cloud = scene
    seg = cloud.gather({n: f.segmentation for n, f in obs.cameras.items()})
    grounder = build_grounder({"kind": "oracle"})
    for obj_id, name in names.items():
        field = grounder.ground(obs, cloud, name, names)
        assert isinstance(field, MaskField) and field.mask.shape == (len(cloud),)
        np.testing.assert_array_equal(field.mask, (seg == obj_id).astype(np.float32))
        assert field.found and field.mask.dtype == np.float32
    missing = grounder.ground(obs, cloud, "pink elephant", names)
    assert not missing.found and missing.mask.sum() == 0


def test_oracle_needs_names_and_segmentation(scene):
    obs, names, cloud = scene
    with pytest.raises(ValueError, match="object_names"):
        OracleGrounder().ground(obs, cloud, "red block", {})
    no_seg = Observation({n: CameraFrame(f.rgb, f.depth, f.intrinsics, f.extrinsics) for n, f in obs.cameras.items()},
                         1.0)
    with pytest.raises(ValueError, match="segmentation"):
        OracleGrounder().ground(no_seg, cloud, next(iter(names.values())), names)
    partial = Observation({"front": obs.cameras["front"]}, 1.0)
    with pytest.raises(KeyError, match="lacks"):
        OracleGrounder().ground(partial, cloud, "x", names)


def test_name_matching():
    names = {0: "red_block", 1: "Blue Block", 2: "red mug", 3: "blue mug"}
    assert match_object_ids("red block", names) == [0]
    assert match_object_ids("the blue block", names) == [1]
    assert match_object_ids("red", names) == []  # ambiguous (block or mug): nothing
    assert match_object_ids("mug", names) == []
    assert match_object_ids("green block", names) == []
    assert match_object_ids("block", {5: "wooden block", 6: "plate"}) == [5]


def test_unknown_grounder_and_options():
    with pytest.raises(ValueError, match="unknown grounder"):
        build_grounder({"kind": "sam"})
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['model'\] for the 'oracle' grounder"):
        build_grounder({"kind": "oracle", "model": "tiny"})
    with pytest.raises(ValueError, match="takes no options"):
        build_grounder({"kind": "oracle"}, cache=None)


def test_clip_grounder_interface(scene, backbone):
    obs, names, cloud = scene
    grounder = ClipGrounder(backbone=backbone, mode="field")  # the per-point field (proposals: their own tests)
    field = grounder.ground(obs, cloud, "red block", names)
    assert field.mask.shape == field.heatmap.shape == (len(cloud),)
    assert field.mask.dtype == np.float32 and set(np.unique(field.mask)) <= {0.0, 1.0}
    assert field.prompt == "a photo of a red block" and field.mask.sum() >= 1
    assert np.all((field.heatmap >= 0) & (field.heatmap <= 1))  # softmax by default
    feats = grounder.point_features(obs, cloud)
    assert feats.shape == (len(cloud), backbone.embed_dim) and feats.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(feats, axis=1), 1.0, atol=1e-5)
    text = grounder.text_features([field.prompt])[0]
    np.testing.assert_allclose(field.similarity, feats @ text, atol=1e-5)
    minmax = build_grounder(ClipGrounderConfig(normalization="minmax", threshold=0.9, mode="field"), backbone=backbone)
    f2 = minmax.ground(obs, cloud, "red block", names)
    assert f2.found and f2.heatmap.max() == pytest.approx(1.0) and f2.heatmap.min() == pytest.approx(0.0)
    assert np.all(f2.mask == (f2.heatmap >= 0.9))


def test_cache_hit_avoids_recomputation(scene, backbone, tmp_path):
    obs, names, cloud = scene
    grounder = ClipGrounder(backbone=backbone, cache=tmp_path, mode="field")
    first = grounder.ground(obs, cloud, "green block", names)
    assert grounder.backbone_calls == len(obs.cameras)
    again = grounder.ground(obs, cloud, "green block", names)
    other_prompt = grounder.ground(obs, cloud, "blue block", names)  # new prompt: features come from the cache
    assert grounder.backbone_calls == len(obs.cameras)
    np.testing.assert_array_equal(first.mask, again.mask)
    assert other_prompt.prompt == "a photo of a blue block"
    # a fresh grounder on the same folder reads everything from disk
    fresh = ClipGrounder(backbone=backbone, cache=GroundingCache(tmp_path), mode="field")
    from_disk = fresh.ground(obs, cloud, "green block", names)
    assert fresh.backbone_calls == 0 and fresh.cache.hits >= 1
    np.testing.assert_array_equal(from_disk.heatmap, first.heatmap)
    assert from_disk.found == first.found
    # changing one camera image recomputes that camera only
    changed = dict(obs.cameras)
    f = changed["front"]
    changed["front"] = CameraFrame(255 - f.rgb, f.depth, f.intrinsics, f.extrinsics, f.segmentation)
    fresh.ground(Observation(changed, 1.0), cloud, "green block", names)
    assert fresh.backbone_calls == 1


def test_cache_survives_corrupt_entries(tmp_path):
    cache = GroundingCache(tmp_path, memory_items=1)
    cache.put("ab" + "0" * 38, {"x": np.arange(3)})
    cache.put("cd" + "0" * 38, {"x": np.arange(4)})  # evicts the first from memory
    np.testing.assert_array_equal(cache.get("ab" + "0" * 38)["x"], np.arange(3))  # from disk
    (tmp_path / "ef").mkdir()
    (tmp_path / "ef" / ("ef" + "0" * 38 + ".npz")).write_bytes(b"not a zip")
    assert cache.get("ef" + "0" * 38) is None


def test_metric_scores(scene):
    obs, names, cloud = scene
    name = names[0]
    target = target_point_mask(obs, cloud, name, names)
    perfect = score_mask(cloud.xyz, target, target)
    assert perfect.precision == 1.0 and perfect.recall == 1.0 and perfect.hit
    assert perfect.center_distance == pytest.approx(0.0, abs=1e-6)
    other = target_point_mask(obs, cloud, names[1], names)
    wrong = score_mask(cloud.xyz, other, target)
    assert wrong.precision == 0.0 and not wrong.hit and wrong.center_distance > 0.05
    empty = score_mask(cloud.xyz, np.zeros(len(cloud)), target, found=False)
    assert np.isnan(empty.precision) and not empty.hit
    summary = summarize([perfect, wrong, empty])
    assert summary["count"] == 3 and summary["hit_rate"] == pytest.approx(1 / 3)
    assert summary["precision"] == pytest.approx(0.5)


def test_ground_command_writes_pngs(tmp_path):
    from abm.cli import main

    out = tmp_path / "g"
    assert main(["ground", "--out", str(out), "--instruction", "please put the blue block in the plate",
                 "--resolution", "64"]) == 0
    files = {p.name for p in out.iterdir()}
    assert {"topdown.png", "views.png", "summary.json", "camera_front.png", "view_top.png"} <= files
    summary = json.loads((out / "summary.json").read_text())
    assert summary["target"] == "blue block" and summary["skill"] == "put X in the plate"
    assert summary["found"] and summary["mask_points"] > 0
    assert main(["ground", "--out", str(out), "--instruction", "sing a song"]) == 2


def test_ground_command_reports_a_target_the_scene_does_not_hold(tmp_path, capsys):
    """Not a silent "0 points masked": a warning naming the scene's objects, NOT FOUND on the images, and
    with --strict a non-zero exit (the images are still written)."""
    from PIL import Image

    from abm.cli import main

    out = tmp_path / "g"
    args = ["ground", "--out", str(out), "--instruction", "put the purple teapot in the plate", "--resolution", "32"]
    assert main(args) == 0
    err = capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    held = summary["scene_objects"]
    assert not summary["target_in_scene"] and not summary["found"] and held
    assert f"'purple teapot' is not in the scene (no object has that name) (the scene holds: {', '.join(held)}" in err
    assert summary["decision"]["found"] is False and summary["decision"]["candidates"] == []
    for name in ("views.png", "topdown.png", "camera_front.png"):
        assert Image.open(out / name).getpixel((1, 1)) == (200, 0, 0)  # the red NOT FOUND caption
    assert main(args + ["--strict"]) == 2
    assert "abm: error: no target to act on for 'put the purple teapot in the plate': 'purple teapot' is not in " \
        "the scene" in capsys.readouterr().err
    assert main(["ground", "--out", str(tmp_path / "ok"), "--resolution", "32", "--strict",
                 "--instruction", f"put the {held[0]} in the plate"]) == 0
    assert Image.open(tmp_path / "ok" / "views.png").getpixel((1, 1)) != (200, 0, 0)


def test_ground_command_bad_inputs_are_one_line_errors(tmp_path, capsys):

    from abm.cli import main

    assert main(["ground", "--out", str(tmp_path / "g"), "--instruction", "  "]) == 2
    assert "--instruction is empty" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert main(["ground", "--out", str(tmp_path / "file")]) == 2
    assert "is a file" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main(["ground", "--out", str(tmp_path / "g"), "--device", "cuda"]) == 2
        assert "CUDA is not available" in capsys.readouterr().err
    assert not (tmp_path / "g").exists()
    for flags, named in ((["--mode", "field"], "--mode, --dense-mode"), (["--threshold", "0.5"], "--clip-model, "),
                         (["--clip-model", "tiny"], "--clip-model, ")):  # CLIP options of a grounder without CLIP
        assert main(["ground", "--out", str(tmp_path / "o"), "--grounder", "oracle", *flags]) == 2
        err = capsys.readouterr().err
        assert named in err and "apply to --grounder clip only" in err and not (tmp_path / "o").exists()


def test_ground_command_on_an_episode_file(tmp_path):
    try:
        from abm.data.episode_store import save_episode
    except ImportError as err:  # the store needs its optional dependencies
        pytest.skip(f"episode store unavailable: {err}")
    from abm.cli import main
    from abm.types import Episode, KeyframeAction

    obs, names = synthetic_scene(seed=1, resolution=48)
    target = names[1]
    action = KeyframeAction(np.array([0.5, 0.0, 0.2]), np.array([0.0, 0.0, 0.0, 1.0]), True)
    episode = Episode("pick_block", 0, "seen", f"put the {target} on the target", names, [target], [(obs, action)],
                      True)
    path = tmp_path / "episode.h5"
    save_episode(episode, path)
    out = tmp_path / "out"
    assert main(["ground", "--episode", str(path), "--step", "0", "--out", str(out), "--resolution", "48"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["target"] == target and summary["found"]
    assert main(["ground", "--episode", str(path), "--step", "5", "--out", str(out)]) == 2
