"""The paper-tables report (benchmarks/paper_tables_report.py): records, averages, stages and the zoo index."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
paper_tables_report = pytest.importorskip("paper_tables_report")
TASKS = paper_tables_report.TASKS


def _rate(task: str, split: str, per_repeat: list[float]) -> dict:
    mean = sum(per_repeat) / len(per_repeat)
    return {"method": "abm", "task": task, "split": split, "per_repeat": per_repeat,
            "episodes": 25 * len(per_repeat), "errors": 0, "mean": mean, "std": 0.0}


def _write_eval(out: Path, run: str, split: str, rates: list[dict]) -> None:
    folder = out / "eval" / run / split
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps(rates))


def test_records_averages_and_tables_fill_in_stages(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    _write_eval(out, "abm_clip", "seen", [_rate(t, "seen", [80.0, 60.0]) for t in TASKS])
    _write_eval(out, "abm_clip", "unseen", [_rate(t, "unseen", [40.0, 60.0]) for t in TASKS[:-1]])  # one missing
    _write_eval(out, "abm_clip", "compositional",
                [_rate(t, "compositional", [20.0, 20.0]) for t in paper_tables_report.COMPOSITIONAL])
    cells = paper_tables_report.collect(out)
    recs = paper_tables_report.records(cells)
    # abm_clip belongs to table 1 (seen/unseen cells) and table 2 (compositional cells); table 3's center-pixel
    # row is abm_clip_hash, worded like the ablations
    assert {r["table"] for r in recs if r["split"] == "compositional"} == {2}
    assert {r["table"] for r in recs if r["split"] != "compositional"} == {1}
    cell = next(r for r in recs if r["table"] == 1 and r["task"] == "close_jar" and r["split"] == "seen")
    assert (cell["successes"], cell["episodes"], cell["grounder"]) == (35, 50, "clip")
    assert paper_tables_report.average(cells, "abm_clip", "seen") == 70.0
    assert paper_tables_report.average(cells, "abm_clip", "unseen") is None  # water_plants not evaluated yet
    t1 = paper_tables_report.table1(cells)
    assert "| close_jar | – | – | – | – | 70 ± 0 (35/50) | 50 ± 0 (25/50) | – | – | – | – |" in t1
    assert "**70.0**" in t1 and "74.2" in t1  # ours beside the paper's
    t2 = paper_tables_report.table2(cells)
    assert "| ABM (CLIP mask field, CLIP skill text) | 20 ± 0 (10/50) | 20 ± 0 (10/50) | 20.0 | 53.2 |" in t2
    assert "| center-pixel (abm_clip_hash) | – | – | – | 70.0 | 57.5 |" in paper_tables_report.table3(cells)
    _write_eval(out, "abm_clip_hash", "seen", [_rate(t, "seen", [40.0, 40.0]) for t in TASKS])
    cells = paper_tables_report.collect(out)
    assert "| center-pixel (abm_clip_hash) | 40.0 | – | – | 70.0 | 57.5 |" in paper_tables_report.table3(cells)
    goals = paper_tables_report.targets(cells)
    assert "abm_clip: seen ≥ 60 %: met (70.0); unseen ≥ 0.85 × seen: not evaluated yet" in goals
    assert paper_tables_report.fusion_spread(cells) == ""  # only once every fusion has both averages
    for run, rate in (("stack", 20.0), ("concat-rerendered", 30.0), ("concat-full", 50.0)):
        for split in ("seen", "unseen"):
            _write_eval(out, run, split, [_rate(t, split, [rate, rate]) for t in TASKS])
    _write_eval(out, "abm_clip_hash", "unseen", [_rate(t, "unseen", [10.0, 10.0]) for t in TASKS])
    spread = paper_tables_report.fusion_spread(paper_tables_report.collect(out))
    assert "span 20.0–50.0 % seen and 10.0–50.0 % unseen (the paper's: 70.0–72.8 and 54.7–57.5)" in spread
    assert "abm_clip_hash: seen ≥ 60 %: not met (40.0)" in goals


def test_zoo_index_describes_exported_models(tmp_path: Path) -> None:
    out, zoo = tmp_path / "paper", tmp_path / "models"
    zoo.mkdir()
    (zoo / "abm_oracle.pt").write_bytes(b"weights")
    run = out / "abm_oracle"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({
        "train": {"tasks": list(TASKS), "data": "runs/paper/data", "steps": 5000, "batch": 8, "optimizer": "adamw",
                  "warmup": 50, "weight_decay": 1e-4, "seed": 0},
        "lr": 1e-3, "policy": {"resolution": 64, "patch_size": 8, "preset": "small+custom"},
        "language": {"kind": "hash"}, "grounder": {"kind": "oracle"}}))
    (run / "log.csv").write_text("step,lr,total,translation,rotation,gripper,collision,samples_per_s,elapsed_s\n"
                                 "10,0.001,1,1,1,1,1,6.5,60\n5000,0,0.2,0.1,0.1,0,0,6.9,7200\n")
    entries = paper_tables_report.zoo_index(out, zoo, None)
    assert [e["name"] for e in entries] == ["abm_oracle"]
    e = entries[0]
    assert e["sha256"] == hashlib.sha256(b"weights").hexdigest() and e["size_bytes"] == 7
    assert (e["steps"], e["train_minutes"], e["recipe"]["resolution"], e["grounder"]) == (5000, 120.0, 64, "oracle")
    assert json.loads((zoo / "index.json").read_text()) == entries
    # on a fresh clone the run folder is gone: the index keeps what it knew, and re-hashes the file
    (zoo / "abm_oracle.pt").write_bytes(b"other")
    again = paper_tables_report.zoo_index(tmp_path / "gone", zoo, None)
    assert again[0]["train_minutes"] == 120.0 and again[0]["sha256"] == hashlib.sha256(b"other").hexdigest()
    row = "| abm_oracle | ABM, oracle mask (upper bound) | abm | oracle | 5000 | 120.0 |"
    assert row in (zoo / "README.md").read_text()


def test_keyframe_accuracy_table_puts_runs_side_by_side_per_task_and_kind(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    (out / "keyframe_accuracy").mkdir(parents=True)

    def row(task: str, kind: str, split: str, cm: float, deg: float) -> dict:
        return {"method": "abm", "task": task, "split": split, "kind": kind, "n": 5, "position_cm_median": cm,
                "within_grasp_tolerance": 1.0, "rotation_deg_median": deg, "gripper_agrees": 1.0}

    (out / "keyframe_accuracy" / "abm_oracle.json").write_text(json.dumps({"summary": [
        row("place_food", "grasp", "seen", 0.44, 5.2), row("close_jar", "grasp", "seen", 0.5, 7.0),
        row("close_jar", "grasp", "unseen", 9.0, 90.0)]}))
    (out / "keyframe_accuracy" / "rvt_clip.json").write_text(json.dumps({"summary": [
        row("close_jar", "grasp", "seen", 3.0, 40.0)]}))
    # a CLIP-grounded mask run is also scored with the oracle mask (RUN@oracle), in the column beside it
    (out / "keyframe_accuracy" / "abm_clip@oracle.json").write_text(json.dumps({"summary": [
        row("close_jar", "grasp", "seen", 1.0, 10.0)]}))
    (out / "keyframe_accuracy" / "abm_clip.json").write_text(json.dumps({"summary": [
        row("close_jar", "grasp", "seen", 2.0, 20.0)]}))
    summaries = paper_tables_report.keyframe_accuracy(out)
    assert list(summaries) == ["rvt_clip", "abm_clip", "abm_clip@oracle", "abm_oracle"]  # the report's run order
    table = paper_tables_report.keyframe_table(summaries, "seen").splitlines()
    assert table[0] == "| task | keyframe | rvt_clip | abm_clip | abm_clip@oracle | abm_oracle |"
    # tasks in the paper's order, a run without that keyframe shows –
    assert table[2:] == ["| close_jar | grasp | 3.0 / 40 | 2.0 / 20 | 1.0 / 10 | 0.5 / 7 |",
                         "| place_food | grasp | – | – | – | 0.4 / 5 |"]
    # the committed copies include the oracle-mask diagnosis, so a fresh clone restores it
    kept = [copy.name for _, copy in paper_tables_report.finished_results(out, tmp_path / "kept")]
    assert "keyframe_accuracy_abm_clip@oracle.json" in kept and "keyframe_accuracy_rvt_clip@oracle.json" not in kept
    assert "9.0 / 90" in paper_tables_report.keyframe_table(summaries, "unseen")


def test_the_timed_zoo_eval_enters_the_report_once_it_ran(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    assert paper_tables_report.zoo_eval(out) == ""
    (out / "zoo_eval").mkdir(parents=True)
    (out / "zoo_eval" / "results.md").write_text("| method | pick_block |\n|---|---|\n| abm_clip | 60.0 (3/5) |\n")
    assert paper_tables_report.zoo_eval(out) == ""  # still running: no time yet
    (out / "zoo_eval" / "seconds").write_text("545\n")
    text = paper_tables_report.zoo_eval(out)
    assert "took 9 min" in text and "| abm_clip | 60.0 (3/5) |" in text and "5 episodes each" in text


def test_weakest_keyframes_ranks_kinds_by_their_median_error_over_tasks() -> None:
    def row(task: str, kind: str, cm: float) -> dict:
        return {"task": task, "split": "seen", "kind": kind, "position_cm_median": cm, "rotation_deg_median": 0.0}

    rows = [row("a", "grasp", 0.5), row("b", "grasp", 0.7), row("c", "grasp", 9.0),
            row("a", "move", 12.0), row("b", "move", 4.0), row("a", "pour", 30.0)]  # pour: one task only
    text = paper_tables_report.weakest_keyframes({"abm_oracle": rows})
    assert "abm_oracle: move 8.0 cm, grasp 0.7 cm." in text
    assert paper_tables_report.weakest_keyframes({"abm_oracle": rows}, "unseen") == ""


def test_approach_yaw_sets_the_approach_against_the_grasp_per_run() -> None:
    def row(task: str, kind: str, deg: float, split: str = "seen") -> dict:
        return {"task": task, "split": split, "kind": kind, "position_cm_median": 1.0, "rotation_deg_median": deg}

    rows = [row("place_food", "approach", 80.0), row("pick_block", "approach", 20.0),
            row("close_jar", "approach", 30.0), row("place_food", "grasp", 4.0), row("pick_block", "grasp", 6.0),
            row("close_jar", "move", 90.0),
            row("place_food", "approach", 10.0, "unseen")]
    text = paper_tables_report.approach_yaw({"abm_oracle": rows, "rvt_clip": [row("a", "approach", 50.0)]})
    assert "abm_oracle 30° / 5° (place_food 80°)." in text  # medians over tasks; move and unseen left out
    assert "rvt_clip" not in text  # no grasp keyframe to compare with
    assert paper_tables_report.approach_yaw({"abm_oracle": rows}, "unseen") == ""


def test_finished_results_are_kept_and_restored_into_a_fresh_out(tmp_path: Path, monkeypatch) -> None:
    out, docs, zoo = tmp_path / "paper", tmp_path / "docs", tmp_path / "models"
    _write_eval(out, "rvt_clip", "seen", [_rate(t, "seen", [20.0, 40.0]) for t in TASKS])
    # stage times: this session's stamps plus the totals carried from sessions whose folders are gone
    (out / "times.txt").write_text("train_minutes 100\ntrain_start 0\ntrain_end 600\neval_start 600\n")
    assert paper_tables_report._stage_minutes(out / "times.txt") == {"train": 110.0}
    (out / "zoo_eval").mkdir(parents=True)
    (out / "zoo_eval" / "results.md").write_text("| method |\n")  # still running: no seconds yet
    argv = ["paper_tables_report.py", str(out), "--zoo", str(zoo), "--docs", str(docs), "--readme", ""]
    monkeypatch.setattr(sys, "argv", argv)
    paper_tables_report.main()
    kept = docs / "paper_tables"
    assert (kept / "rvt_clip_seen.json").is_file() and (kept / "zoo_eval.md").is_file()
    # the machine that wrote the report is recorded once beside those of earlier sessions
    (kept / "machines.txt").write_text("an earlier machine\n")
    (out / "machines.txt").unlink()
    paper_tables_report.main()
    machine = paper_tables_report._machine()
    assert (kept / "machines.txt").read_text().splitlines() == ["an earlier machine", machine]
    assert f"Machines (every session that ran a stage): an earlier machine; {machine}." in (
        docs / "paper_tables.md").read_text()
    assert not (kept / "zoo_eval_seconds.txt").exists()
    # a fresh clone: nothing under OUT; the script restores first, the report then has the row again
    fresh = tmp_path / "fresh"
    monkeypatch.setattr(sys, "argv", ["paper_tables_report.py", str(fresh), "--docs", str(docs), "--restore-only"])
    paper_tables_report.main()
    assert json.loads((fresh / "eval" / "rvt_clip" / "seen" / "results.json").read_text())[0]["mean"] == 30.0
    assert paper_tables_report._stage_minutes(fresh / "times.txt") == {"train": 110.0}
    assert paper_tables_report.average(paper_tables_report.collect(fresh), "rvt_clip", "seen") == 30.0
    # what OUT has is never overwritten by an older kept copy
    (fresh / "zoo_eval" / "results.md").write_text("newer\n")
    assert paper_tables_report.restore(fresh, kept) == 0
    assert (fresh / "zoo_eval" / "results.md").read_text() == "newer\n"


def test_caveats_appear_only_for_runs_with_cells(monkeypatch) -> None:
    monkeypatch.setattr(paper_tables_report, "CAVEATS", {"abm_clip": "Rerun pending.", "stack": "Other."})
    assert paper_tables_report.caveats({}) == ""
    cells = {("abm_clip", "close_jar", "seen"): _rate("close_jar", "seen", [50.0])}
    assert paper_tables_report.caveats(cells) == "Rerun pending.\n\n"
    assert "Rerun pending." in paper_tables_report.report(Path("/nonexistent"), cells, [], "cmd")
