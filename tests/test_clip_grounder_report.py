"""The CLIP-grounder report (benchmarks/clip_grounder_report.py) reads the labels `abm eval` writes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
clip_grounder_report = pytest.importorskip("clip_grounder_report")


def _rate(method: str, task: str, split: str, per_repeat: list[float]) -> dict:
    mean = sum(per_repeat) / len(per_repeat)
    return {"method": method, "task": task, "split": split, "per_repeat": per_repeat, "episodes": 10 * len(per_repeat),
            "errors": 0, "mean": mean, "std": 0.0}


def test_rows_follow_eval_labels_and_averages() -> None:
    # abm eval names repeated variants "variant (run folder)" and a unique one by its variant alone
    rates = [
        _rate("abm (abm_oracle)", "pick_block", "seen", [80.0, 100.0]),
        _rate("abm (abm_oracle)", "pick_block", "unseen", [60.0, 80.0]),
        _rate("abm (abm_clip)", "pick_block", "seen", [40.0, 60.0]),
        _rate("abm (abm_clip)", "pick_block", "unseen", [20.0, 20.0]),
        _rate("ifd", "pick_block", "seen", [10.0, 10.0]),
        _rate("ifd", "pick_block", "unseen", [0.0, 0.0]),
    ]
    assert clip_grounder_report.run_label("abm_clip", rates) == "abm (abm_clip)"
    assert clip_grounder_report.run_label("ifd_clip", rates) == "ifd"
    assert clip_grounder_report.run_label("rvt_hash", rates) is None
    table, averages = clip_grounder_report.success_table(rates)
    rows = [line for line in table.splitlines() if line.startswith("| abm_") or line.startswith("| ifd_")]
    assert [r.split(" | ")[0] for r in rows] == ["| abm_oracle", "| abm_clip", "| ifd_clip"]
    assert averages["abm_oracle"] == {"seen": 90.0, "unseen": 70.0}
    assert averages["abm_clip"] == {"seen": 50.0, "unseen": 20.0}
    assert "18/20" in rows[0] and "4/20" in rows[1]  # successes out of all episodes of the repeats
    assert rows[1].endswith("| 50 | 20 | 0.40 |")


def test_mask_quality_uses_the_trained_model_at_the_grounders_setting() -> None:
    case = {"model": "trained", "task": "pick_block", "split": "seen", "normalization": "softmax", "threshold": 0.7,
            "iou": 0.3, "precision": 0.5, "recall": 0.4, "hit": 1.0, "top1": 0.0}
    cases = [case, {**case, "iou": 0.1, "hit": 0.0, "top1": 1.0},
             {**case, "threshold": 0.3, "iou": 0.9},  # another threshold: ignored
             {**case, "model": "random weights", "iou": 0.0}]  # another model: ignored
    text = clip_grounder_report.mask_quality({"mask_cases": cases}, ["pick_block"], "softmax", 0.7)
    assert "| pick_block | seen | 2 | 0.20 | 0.50 | 0.40 | 50 % | 50 % |" in text
    assert clip_grounder_report.mask_quality({"mask_cases": cases}, ["place_food"], "softmax", 0.7) == ""


def test_report_is_written_from_a_run_folder(tmp_path: Path) -> None:
    out = tmp_path / "run"
    for split in ("seen", "unseen"):
        (out / f"eval_{split}").mkdir(parents=True)
        rates = [_rate(f"{v} ({n})", "pick_block", split, [50.0]) for n, (v, _) in clip_grounder_report.RUNS.items()
                 if v != "ifd"] + [_rate("ifd", "pick_block", split, [0.0])]
        (out / f"eval_{split}" / "results.json").write_text(json.dumps(rates))
        swapped = out / f"eval_{split}_oracle_trained_clip"  # abm_oracle evaluated alone: labelled "abm"
        swapped.mkdir()
        (swapped / "results.json").write_text(json.dumps([_rate("abm", "pick_block", split, [30.0])]))
    for name in clip_grounder_report.RUNS:
        (out / name).mkdir()
        (out / name / "log.csv").write_text("step,lr,total,translation,rotation,gripper,collision,samples_per_s,"
                                           "elapsed_s\n10,0.001,1,1,1,1,1,8.0,60\n20,0.001,1,1,1,1,1,8.0,120\n")
    config = {"train": {"steps": 20, "batch": 8, "optimizer": "adamw", "lr": 0.001, "grounder_options": {}},
              "policy": {"resolution": 48, "workspace_size": 0.6}}
    (out / "abm_clip" / "config.json").write_text(json.dumps(config))
    text, summary = clip_grounder_report.report(out, tmp_path / "no_clip", "bash scripts/clip_grounder.sh")
    assert text == summary  # no mask-quality JSON given
    assert "abm keeps 50 % / 50 % = 1.00 of the oracle's unseen success" in text
    assert "CLIP text moves rvt from 50 % to 50 %" in text
    assert "20 steps of batch 8" in text and "abm_oracle 2 min" in text
    assert "| abm_oracle → CLIP | abm | trained on oracle masks" in text
    assert "grounded by CLIP only at evaluation reaches 30 % / 30 % (seen / unseen), the CLIP-trained one 50 %" in text


def test_grounding_quality_rows_and_runs_left_out(tmp_path: Path) -> None:
    record = {"config": "proposals (combined, no split)", "task": "pick_block", "split": "unseen", "iou": 0.81,
              "hit_rate": 0.9, "top1": 0.7, "n": 10}
    quality = {"records": [record, {**record, "config": "field (maskclip)", "iou": 0.1}]}
    text = clip_grounder_report.grounding_quality(quality, ["pick_block"], "proposals (combined, no split)")
    assert text.splitlines()[2:] == ["| pick_block | unseen | 10 | 0.81 | 90 % | 70 % |"]
    assert clip_grounder_report.grounding_quality(quality, ["place_food"], "field (maskclip)") == ""

    out = tmp_path / "run"  # only the two abm runs evaluated (METHODS="abm_oracle abm_clip")
    for split in ("seen", "unseen"):
        (out / f"eval_{split}").mkdir(parents=True)
        rates = [_rate(f"abm ({n})", "pick_block", split, [50.0]) for n in ("abm_oracle", "abm_clip")]
        (out / f"eval_{split}" / "results.json").write_text(json.dumps(rates))
    (out / "abm_clip").mkdir()
    config = {"train": {"steps": 20, "batch": 8, "optimizer": "adamw", "lr": 0.001, "grounder_options": {}},
              "policy": {"resolution": 48, "workspace_size": 0.6}}
    (out / "abm_clip" / "config.json").write_text(json.dumps(config))
    text, summary = clip_grounder_report.report(out, tmp_path / "no_clip", "bash scripts/clip_grounder.sh",
                                                grounding=quality, grounding_config=record["config"])
    left_out = "Not evaluated in this run (the script's METHODS): rvt_hash, rvt_clip, ifd_clip, abm_oracle → CLIP."
    assert left_out in summary
    assert "| pick_block | unseen | 10 | 0.81 | 90 % | 70 % |" in text and "0.81" not in summary
