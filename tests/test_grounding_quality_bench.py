"""The grounding-configuration benchmark (benchmarks/grounding_quality.py --cases): cached cases round-trip,
records average per task and split, and the generated tables replace only the text between the markers."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
grounding_quality = pytest.importorskip("grounding_quality")
grounding_cases = pytest.importorskip("grounding_cases")


def test_cached_case_round_trips(tmp_path):
    from abm.render.synthetic import synthetic_scene

    obs, names = synthetic_scene(seed=0, resolution=32)
    meta = {"task": "pick_block", "split": "unseen", "seed": 3, "instruction": "put the red block on the target",
            "target_name": "red block", "object_names": {str(k): v for k, v in names.items()}}
    grounding_cases.save_case(tmp_path / "pick_block__unseen__3.npz", obs, meta)
    (loaded, got), = list(grounding_cases.load_cases(tmp_path))
    assert got["object_names"] == names and got["seed"] == 3 and list(loaded.cameras) == list(obs.cameras)
    for name, frame in obs.cameras.items():
        np.testing.assert_array_equal(loaded.camera(name).rgb, frame.rgb)
        np.testing.assert_array_equal(loaded.camera(name).segmentation, frame.segmentation)
        np.testing.assert_allclose(loaded.camera(name).extrinsics, frame.extrinsics)
    assert list(grounding_cases.load_cases(tmp_path, seeds=3)) == []


def test_sweep_on_a_cached_case_and_records(tmp_path):
    from abm.grounding.clip import tiny_clip
    from abm.render.synthetic import synthetic_scene

    obs, names = synthetic_scene(seed=1, resolution=48)
    target = next(iter(names.values()))
    meta = {"task": "pick_block", "split": "unseen", "seed": 0, "instruction": f"put the {target} on the target",
            "target_name": target, "object_names": names}
    backbone = tiny_clip()
    grounders = {n: grounding_quality.build_config_grounder(grounding_quality.CONFIGS[n], backbone)
                 for n in ("oracle", "field (naclip)", "proposals (combined)")}
    rows = grounding_quality.sweep([(obs, meta)], grounders)
    assert [r["config"] for r in rows] == list(grounders)
    oracle = rows[0]
    assert oracle["iou"] == oracle["hit"] == oracle["top1"] == 1.0
    rows.append(dict(oracle, seed=1, iou=0.0, hit=0.0, top1=0.0))
    recs = {r["config"]: r for r in grounding_quality.records(rows)}
    assert recs["oracle"]["n"] == 2 and recs["oracle"]["iou"] == 0.5 and recs["oracle"]["hit_rate"] == 0.5
    assert set(recs["oracle"]) >= {"config", "task", "split", "iou", "hit_rate", "top1", "n"}
    json.dumps(list(recs.values()))
    table = grounding_quality.markdown(list(recs.values()), list(grounders))
    assert "| oracle | 0.500 | 0.50 |" in table

    doc = tmp_path / "doc.md"
    doc.write_text(f"before\n{grounding_quality.DOC_BEGIN}\nold\n{grounding_quality.DOC_END}\nafter\n")
    assert grounding_quality.write_doc(doc, table)
    text = doc.read_text()
    assert text.startswith("before\n") and text.endswith("after\n") and "old" not in text and table in text
    (tmp_path / "plain.md").write_text("no markers\n")
    assert not grounding_quality.write_doc(tmp_path / "plain.md", table)
