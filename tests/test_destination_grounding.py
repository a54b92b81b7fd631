"""The destination's grounding quality as a diagnosis the engine runs (issue 54): the ``destination_grounding``
request (what ``benchmarks/destination_grounding.py`` measured by hand, now a thin command line over it), its one
job per spec for the spec's CLIP, its kept JSON and the report section that shows it."""

from __future__ import annotations

import json
import math
import runpy
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from abm.evaluation.diagnose import DIAGNOSES
from abm.evaluation.diagnose import from_dict as diagnosis_from_dict
from abm.evaluation.diagnose.destination_grounding import DestinationGrounding, markdown, point_iou
from abm.experiments import report as rep
from abm.experiments.jobs import DiagnoseJob
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import DESTINATION_GROUNDING_JOB, LEFT, Engine
from abm.experiments.state import Layout, keep, kept_pairs, restore

REPO = Path(__file__).resolve().parents[1]
V3 = load_spec("paper_tables_v3")
MEASURED = REPO / "docs/results/destination_grounding.json"  # benchmarks/destination_grounding.py --episodes 3


def test_point_iou_counts_the_masked_points_against_the_true_ones() -> None:
    mask, truth = np.array([0.9, 0.8, 0.1, 0.0]), np.array([True, False, True, False])
    assert point_iou(mask, truth) == pytest.approx(1 / 3)  # one shared of three in either
    assert point_iou(np.zeros(4), np.zeros(4, bool)) != point_iou(np.zeros(4), np.zeros(4, bool))  # NaN: both empty
    assert point_iou(np.ones(4), np.ones(4, bool)) == 1.0


def test_the_request_is_a_registered_diagnosis_that_round_trips_through_a_job_file(tmp_path: Path) -> None:
    assert DIAGNOSES["destination_grounding"].request_class() is DestinationGrounding
    request = DestinationGrounding("models/benchmark-clip", Path("out/dg.json"), tasks=("place_wine",),
                                   splits=("unseen",), episodes=2)
    assert diagnosis_from_dict(json.loads(json.dumps(request.to_dict()))) == request
    job = DiagnoseJob(request)
    job.write(tmp_path / "job.json")
    assert DiagnoseJob.from_dict(json.loads((tmp_path / "job.json").read_text())) == job


def test_the_oracle_grounds_target_and_destination_exactly_and_the_rows_keep_the_benchmarks_format(
        tmp_path: Path) -> None:
    """The oracle's masks are the segmentation itself (IoU 1, every centre a hit); a task without a destination
    (take_off_pan) has a target row only; the JSON is the list of rows docs/results/destination_grounding.json
    holds."""
    out = tmp_path / "dg.json"
    rows = DestinationGrounding(None, out, tasks=("place_wine", "take_off_pan"), splits=("seen",), episodes=1,
                                resolution=64, grounder="oracle").run()
    assert [(r["task"], r["object"]) for r in rows] == [("place_wine", "target"), ("place_wine", "destination"),
                                                          ("take_off_pan", "target")]
    assert all((r["split"], r["n"], r["iou"], r["hit_rate"], r["found_rate"]) == ("seen", 1, 1.0, 1.0, 1.0)
               for r in rows)
    assert json.loads(out.read_text()) == rows
    committed = json.loads(MEASURED.read_text())
    assert all(list(row) == list(rows[0]) for row in committed)  # the same keys in the same order
    table = markdown(rows).splitlines()
    assert table[0] == "| task | split | object | n | IoU | hit rate | found rate |"
    assert table[3] == "| place_wine | seen | destination | 1 | 1.00 | 1.00 | 1.00 |"


def test_the_benchmark_is_a_command_line_over_the_request(monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    asked: list[DestinationGrounding] = []

    def measured(self: DestinationGrounding) -> list[dict]:
        asked.append(self)
        return [r for r in json.loads(MEASURED.read_text()) if r["task"] == "pick_block"]

    monkeypatch.setattr(DestinationGrounding, "run", measured)
    monkeypatch.setattr(sys, "argv", ["destination_grounding.py", "--episodes", "3", "--tasks", "pick_block",
                                      "--out", "x.json"])
    runpy.run_path(str(REPO / "benchmarks/destination_grounding.py"), run_name="__main__")
    assert asked == [DestinationGrounding("models/benchmark-clip", Path("x.json"), tasks=("pick_block",),
                                          episodes=3)]
    printed = capsys.readouterr().out
    assert "| pick_block | unseen | destination | 3 | 0.00 | 0.00 | 0.00 |" in printed


def test_the_spec_asks_for_it_once_and_the_engine_plans_one_job_for_the_specs_clip(tmp_path: Path) -> None:
    dg = V3.diagnose.destination_grounding if V3.diagnose else None
    assert dg is not None and (dg.episodes, dg.splits, dg.tasks) == (5, ("seen", "unseen"), None)
    root = tmp_path / "clone"
    (root / "models").mkdir(parents=True)
    (root / "models/benchmark-clip").symlink_to(REPO / "models/benchmark-clip")
    jobs = {j.id: j for j in Engine(V3, root=root, runs=["rvt_clip"]).plan("diagnose")}
    job = jobs[DESTINATION_GROUNDING_JOB]  # of the grounder, whichever runs are chosen
    assert job.state == LEFT and isinstance(job.work, DiagnoseJob)
    assert job.work.request == DestinationGrounding(
        "models/benchmark-clip", Path("runs/paper_v3/destination_grounding.json"), tasks=V3.training.tasks,
        splits=("seen", "unseen"), episodes=5, resolution=V3.data.resolution)
    assert [i for i in jobs if "destination" in i] == [DESTINATION_GROUNDING_JOB]
    (root / "models/benchmark-clip").unlink()  # without the CLIP it waits for it
    assert Engine(V3, root=root).plan("diagnose")[-1].note == "no benchmark CLIP"
    # no other spec asks for it: their diagnoses are as they were
    assert all(DESTINATION_GROUNDING_JOB not in {j.id for j in Engine(load_spec(name), root=root).plan("diagnose")}
               for name in ("paper_tables", "paper_tables_v2"))


def test_its_json_is_kept_restored_and_done_on_a_fresh_clone(tmp_path: Path) -> None:
    layout = Layout.of(V3, tmp_path)
    pairs = dict(kept_pairs(V3, layout))
    assert pairs[layout.destination_grounding] == tmp_path / "docs/results/paper_tables_v3/destination_grounding.json"
    assert layout.destination_grounding not in dict(kept_pairs(load_spec("paper_tables_v2"), layout))
    layout.destination_grounding.parent.mkdir(parents=True)
    layout.destination_grounding.write_text(MEASURED.read_text())
    assert keep(V3, layout) == 1
    layout.destination_grounding.unlink()
    assert restore(V3, layout) == 1 and layout.destination_grounding.read_text() == MEASURED.read_text()
    assert rep.collect(V3, layout).destination_grounding == json.loads(MEASURED.read_text())


def test_the_section_shows_target_and_destination_per_task_and_split(tmp_path: Path) -> None:
    section = next(s for s in V3.report.summary if s.kind == "destination_grounding")
    layout = Layout.of(V3, tmp_path, tmp_path / "out")
    empty = rep.Context(V3, rep.Outcomes(cells={}), layout)
    assert rep.write_section(empty, section) == []  # not measured yet: nothing
    rows = json.loads(MEASURED.read_text())
    rows.append({"task": "take_off_pan", "split": "seen", "object": "target", "n": 3, "iou": math.nan,
                 "hit_rate": 0.0, "found_rate": 0.0})
    title, table, note = rep.write_section(rep.Context(V3, rep.Outcomes(cells={}, destination_grounding=rows),
                                                       layout), section)
    assert title == section.title
    lines = table.splitlines()
    assert lines[0] == ("| task | split | scenes | target IoU | target hit rate | destination IoU | "
                        "destination hit rate |")
    tasks = [line.split(" | ")[0].removeprefix("| ") for line in lines[2:]]
    in_order = ["close_jar", "insert_peg", "pick_block", "place_food", "place_wine", "put_in_shelf", "take_off_pan",
                "water_plants", "put_in_container"]  # the spec's task order, then a task it does not train
    assert tasks == [t for t in in_order for _ in range(1 if t == "take_off_pan" else 2)]
    assert "| pick_block | seen | 3 | 0.98 | 100 % | 0.00 | 0 % |" in lines
    assert "| water_plants | unseen | 3 | 0.64 | 67 % | 0.99 | 100 % |" in lines
    assert "| take_off_pan | seen | 3 | – | 0 % | none | none |" in lines  # no IoU, no destination
    assert "`models/benchmark-clip`" in note and "docs/results/paper_tables_v3/destination_grounding.json" in note


def test_a_spec_asks_for_it_with_its_clip_and_known_splits(tmp_path: Path) -> None:
    data = yaml.safe_load((REPO / "src/abm/configs/experiments/seen_unseen.yaml").read_text())  # no clip: folder
    data["diagnose"] = {"destination_grounding": {"episodes": 2}}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="clip: diagnose.destination_grounding measures the spec's CLIP grounder"):
        load_spec(bad)
    data["clip"] = "models/benchmark-clip"
    data["diagnose"] = {"destination_grounding": {"splits": ["elsewhere"]}}
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="diagnose.destination_grounding.splits: 'elsewhere' is no object split"):
        load_spec(bad)
    data["diagnose"] = {"destination_grounding": {"episodes": 2, "tasks": ["place_wine"], "extra": 1}}
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="extra"):
        load_spec(bad)
    data["diagnose"]["destination_grounding"].pop("extra")
    bad.write_text(yaml.safe_dump(data))
    loaded = load_spec(bad)
    assert loaded.diagnose is not None and loaded.diagnose.destination_grounding == replace(
        V3.diagnose.destination_grounding, episodes=2, tasks=("place_wine",))  # type: ignore[union-attr]
