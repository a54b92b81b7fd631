"""The report module (abm.experiments.report) on the paper-tables spec: the committed report regenerates from
the committed outcomes byte for byte, and its tables, records, targets, diagnosis sentences, zoo index and kept
outcomes behave as the tables fill in stages.

The regenerated blocks equal the ones the deleted ``benchmarks/paper_tables_report.py`` wrote, after one
documented normalisation: the provenance line names ``abm experiment run paper_tables`` and its spec instead of
the script, and the stage times say "Wall time per stage," instead of "... of the script's runs,".
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from abm.experiments import report as rep
from abm.experiments.spec import load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import Layout, keep, kept_pairs, restore, stage_minutes
from abm.policy.config import PolicyConfig

REPO = Path(__file__).resolve().parents[1]
SPEC = load_spec("paper_tables")
TASKS = SPEC.split_tasks()["seen"]
COMPOSITIONAL = SPEC.split_tasks()["compositional"]


#: what a paper-tables report writes or leaves as it is (every edition): its document and records, the README, the
#: zoo's index and README; the third edition's also reads the earlier editions' records (its editions table)
WRITTEN = {"paper_tables": ("docs/results/paper_tables.json", "docs/results/paper_tables.md", "README.md",
                            "models/index.json", "models/README.md"),
           "paper_tables_v2": ("docs/results/paper_tables_v2.json", "docs/results/paper_tables_v2.md", "README.md",
                               "models/index.json", "models/README.md"),
           "paper_tables_v3": ("docs/results/paper_tables_v3.json", "docs/results/paper_tables_v3.md", "README.md",
                               "models/index.json", "models/README.md", "docs/results/paper_tables.json",
                               "docs/results/paper_tables_v2.json")}


def _committed_root(tmp_path: Path, spec=SPEC) -> Path:
    """A scratch root holding copies of what a paper-tables report reads and writes (the model files and
    the benchmark CLIP linked, read only)."""
    root = tmp_path / "root"
    shutil.copytree(REPO / spec.kept, root / spec.kept)
    for name in WRITTEN[spec.name]:
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(REPO / name, root / name)
    for model in (REPO / "models").iterdir():
        if model.suffix == ".pt" or model.name == "benchmark-clip":
            (root / "models" / model.name).symlink_to(model)
    return root


def test_the_committed_paper_tables_report_regenerates_from_the_committed_outcomes(tmp_path: Path) -> None:
    root = _committed_root(tmp_path)
    engine = Engine(SPEC, root=root)
    assert engine.run(["report"]) == 0  # a fresh clone: OUT is empty, the kept outcomes are restored first
    assert (root / "runs/paper/eval/abm_clip/seen/results.json").is_file()
    for name in WRITTEN[SPEC.name]:  # the README is the second edition's: this one leaves it as it is
        assert (root / name).read_bytes() == (REPO / name).read_bytes(), f"{name} differs from its regeneration"
    text = (REPO / "docs/results/paper_tables.md").read_text()
    assert "| **average** | **21.2** | **9.5** |" in text and "| stack | 27.2 | 14.8 | 0.54 | 72.8 | 54.9 |" in text
    # the report stage adds no machine: only stages that ran work record one
    assert (root / SPEC.kept / "machines.txt").read_bytes() == (REPO / SPEC.kept / "machines.txt").read_bytes()


def test_the_committed_second_edition_regenerates_from_the_committed_outcomes(tmp_path: Path) -> None:
    v2 = load_spec("paper_tables_v2")
    root = _committed_root(tmp_path, v2)
    assert Engine(v2, root=root).run(["report"]) == 0
    for name in WRITTEN[v2.name]:  # its page, records and zoo index; the README is the third edition's
        assert (root / name).read_bytes() == (REPO / name).read_bytes(), f"{name} differs from its regeneration"


def test_the_committed_third_edition_and_the_readme_blocks_regenerate_from_the_committed_outcomes(
        tmp_path: Path) -> None:
    v3 = load_spec("paper_tables_v3")
    root = _committed_root(tmp_path, v3)
    assert Engine(v3, root=root).run(["report"]) == 0
    for name in WRITTEN[v3.name]:
        assert (root / name).read_bytes() == (REPO / name).read_bytes(), f"{name} differs from its regeneration"
    block = rep.block_of((REPO / "README.md").read_text(), "paper-tables")
    assert block.startswith(
        "Written by `abm experiment run paper_tables_v3` ([src/abm/configs/experiments/paper_tables_v3.yaml]")
    assert "**Table 1**" in block and "**Table 3**" in block and "paper_tables_v2.md" in block  # the earlier edition
    assert "seed spread" in rep.block_of((REPO / "README.md").read_text(), "headline")


def _rate(task: str, split: str, per_repeat: list[float]) -> dict:
    mean = sum(per_repeat) / len(per_repeat)
    return {"method": "abm", "task": task, "split": split, "per_repeat": per_repeat,
            "episodes": 25 * len(per_repeat), "errors": 0, "mean": mean, "std": 0.0}


def _layout(tmp_path: Path) -> Layout:
    return Layout.of(SPEC, tmp_path, tmp_path / "paper")


def _write_eval(layout: Layout, run: str, split: str, rates: list[dict]) -> None:
    folder = layout.eval_dir(run, split)
    folder.mkdir(parents=True)
    (folder / "results.json").write_text(json.dumps(rates))


def _ctx(layout: Layout) -> rep.Context:
    return rep.Context(SPEC, rep.Outcomes(cells=rep.collect_cells(SPEC, layout)), layout)


def _section(table: int):
    return next(s for s in SPEC.report.summary if s.table == table)


def _kind(kind: str):
    return next(s for s in SPEC.report.summary if s.kind == kind)


def test_records_averages_and_tables_fill_in_stages(tmp_path: Path) -> None:
    layout = _layout(tmp_path)
    _write_eval(layout, "abm_clip", "seen", [_rate(t, "seen", [80.0, 60.0]) for t in TASKS])
    _write_eval(layout, "abm_clip", "unseen", [_rate(t, "unseen", [40.0, 60.0]) for t in TASKS[:-1]])  # one missing
    _write_eval(layout, "abm_clip", "compositional", [_rate(t, "compositional", [20.0, 20.0]) for t in COMPOSITIONAL])
    ctx = _ctx(layout)
    recs = rep.records(SPEC, ctx.cells)
    # abm_clip belongs to table 1 (seen/unseen cells) and table 2 (compositional cells); table 3's center-pixel
    # row is abm_clip_hash, worded like the ablations
    assert {r["table"] for r in recs if r["split"] == "compositional"} == {2}
    assert {r["table"] for r in recs if r["split"] != "compositional"} == {1}
    cell = next(r for r in recs if r["table"] == 1 and r["task"] == "close_jar" and r["split"] == "seen")
    assert (cell["successes"], cell["episodes"], cell["grounder"]) == (35, 50, "clip")
    assert ctx.average("abm_clip", "seen") == 70.0
    assert ctx.average("abm_clip", "unseen") is None  # water_plants not evaluated yet
    title, t1 = rep.write_section(ctx, _section(1))
    assert title.startswith("**Table 1**")
    assert "| close_jar | – | – | – | – | 70 ± 0 (35/50) | 50 ± 0 (25/50) | – | – | – | – |" in t1
    assert "**70.0**" in t1 and "74.2" in t1  # ours beside the paper's
    t2 = rep.write_section(ctx, _section(2))[1]
    assert "| ABM (CLIP mask field, CLIP skill text) | 20 ± 0 (10/50) | 20 ± 0 (10/50) | 20.0 | 53.2 |" in t2
    assert "| center-pixel (abm_clip_hash) | – | – | – | 70.0 | 57.5 |" in rep.write_section(ctx, _section(3))[1]
    _write_eval(layout, "abm_clip_hash", "seen", [_rate(t, "seen", [40.0, 40.0]) for t in TASKS])
    ctx = _ctx(layout)
    assert "| center-pixel (abm_clip_hash) | 40.0 | – | – | 70.0 | 57.5 |" in rep.write_section(ctx, _section(3))[1]
    (goals,) = rep.write_section(ctx, _kind("targets"))
    assert "abm_clip: seen ≥ 60 %: met (70.0); unseen ≥ 0.85 × seen: not evaluated yet" in goals
    assert "abm_clip_hash: seen ≥ 60 %: not met (40.0)" in goals
    assert rep.write_section(ctx, _kind("spread")) == []  # only once every fusion has both averages
    for run, rate in (("stack", 20.0), ("concat-rerendered", 30.0), ("concat-full", 50.0)):
        for split in ("seen", "unseen"):
            _write_eval(layout, run, split, [_rate(t, split, [rate, rate]) for t in TASKS])
    _write_eval(layout, "abm_clip_hash", "unseen", [_rate(t, "unseen", [10.0, 10.0]) for t in TASKS])
    (spread,) = rep.write_section(_ctx(layout), _kind("spread"))
    assert "span 20.0–50.0 % seen and 10.0–50.0 % unseen (the paper's: 70.0–72.8 and 54.7–57.5)" in spread


def test_zoo_index_describes_exported_models(tmp_path: Path) -> None:
    layout = Layout.of(SPEC, tmp_path, tmp_path / "paper")
    assert layout.zoo is not None
    layout.zoo.mkdir()
    (layout.zoo / "abm_oracle.pt").write_bytes(b"weights")
    run = layout.run_dir("abm_oracle")
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({
        "train": {"tasks": list(TASKS), "data": "runs/paper/data", "steps": 5000, "batch": 8, "optimizer": "adamw",
                  "warmup": 50, "weight_decay": 1e-4, "seed": 0, "grounder": "oracle", "language": "hash",
                  "policy_overrides": {"resolution": 64, "patch_size": 8}},  # a config.json of the first edition
        "lr": 1e-3, "language": {"kind": "hash"}}))
    (run / "log.csv").write_text("step,lr,total,translation,rotation,gripper,collision,samples_per_s,elapsed_s\n"
                                 "10,0.001,1,1,1,1,1,6.5,60\n5000,0,0.2,0.1,0.1,0,0,6.9,7200\n")
    entries = rep.zoo_index(SPEC, layout)
    assert [e["name"] for e in entries] == ["abm_oracle"]
    e = entries[0]
    assert e["sha256"] == hashlib.sha256(b"weights").hexdigest() and e["size_bytes"] == 7
    assert (e["steps"], e["train_minutes"], e["recipe"]["resolution"], e["grounder"]) == (5000, 120.0, 64, "oracle")
    assert e["tables"] == [1, 2]
    Engine(SPEC, root=tmp_path, out=tmp_path / "paper").write_zoo_index()
    assert json.loads((layout.zoo / "index.json").read_text()) == entries
    # on a fresh clone the run folder is gone: the index keeps what it knew, and re-hashes the file
    (layout.zoo / "abm_oracle.pt").write_bytes(b"other")
    again = rep.zoo_index(SPEC, Layout.of(SPEC, tmp_path, tmp_path / "gone"))
    assert again[0]["train_minutes"] == 120.0 and again[0]["sha256"] == hashlib.sha256(b"other").hexdigest()
    row = "| abm_oracle | ABM, oracle mask (upper bound) | abm | oracle | 5000 | 120.0 |"
    text = rep.zoo_readme(SPEC, layout, again)
    assert row in text and ("([src/abm/configs/experiments/paper_tables.yaml]"
                            "(../src/abm/configs/experiments/paper_tables.yaml))") in text


def _kf_row(task: str, kind: str, split: str, cm: float, deg: float) -> dict:
    return {"method": "abm", "task": task, "split": split, "kind": kind, "n": 5, "position_cm_median": cm,
            "within_grasp_tolerance": 1.0, "rotation_deg_median": deg, "gripper_agrees": 1.0}


def test_keyframe_accuracy_table_puts_runs_side_by_side_per_task_and_kind(tmp_path: Path) -> None:
    layout = _layout(tmp_path)
    layout.diagnosis("x").parent.mkdir(parents=True)
    files = {"abm_oracle": [_kf_row("place_food", "grasp", "seen", 0.44, 5.2),
                            _kf_row("close_jar", "grasp", "seen", 0.5, 7.0),
                            _kf_row("close_jar", "grasp", "unseen", 9.0, 90.0)],
             "rvt_clip": [_kf_row("close_jar", "grasp", "seen", 3.0, 40.0)],
             # a CLIP-grounded mask run is also scored with the oracle mask (RUN@oracle), in the column beside it
             "abm_clip@oracle": [_kf_row("close_jar", "grasp", "seen", 1.0, 10.0)],
             "abm_clip": [_kf_row("close_jar", "grasp", "seen", 2.0, 20.0)]}
    for name, rows in files.items():
        layout.diagnosis(name).write_text(json.dumps({"summary": rows}))
    summaries = rep.keyframe_summaries(SPEC, layout)
    assert list(summaries) == ["rvt_clip", "abm_clip", "abm_clip@oracle", "abm_oracle"]  # the report's run order
    order = {t: i for i, t in enumerate(TASKS)}
    table = rep.keyframe_table(summaries, "seen", order).splitlines()
    assert table[0] == "| task | keyframe | rvt_clip | abm_clip | abm_clip@oracle | abm_oracle |"
    # tasks in the paper's order, a run without that keyframe shows –
    assert table[2:] == ["| close_jar | grasp | 3.0 / 40 | 2.0 / 20 | 1.0 / 10 | 0.5 / 7 |",
                         "| place_food | grasp | – | – | – | 0.4 / 5 |"]
    # the committed copies include the oracle-mask diagnosis, so a fresh clone restores it
    kept = [copy.name for _, copy in kept_pairs(SPEC, layout)]
    assert "keyframe_accuracy_abm_clip@oracle.json" in kept and "keyframe_accuracy_rvt_clip@oracle.json" not in kept
    assert "9.0 / 90" in rep.keyframe_table(summaries, "unseen", order)


def test_the_timed_zoo_eval_enters_the_report_once_it_ran(tmp_path: Path) -> None:
    layout = _layout(tmp_path)
    assert rep.collect(SPEC, layout).zoo_eval is None
    layout.zoo_eval.mkdir(parents=True)
    (layout.zoo_eval / "results.md").write_text("| method | pick_block |\n|---|---|\n| abm_clip | 60.0 (3/5) |\n")
    assert rep.collect(SPEC, layout).zoo_eval is None  # still running: no time yet
    (layout.zoo_eval / "seconds").write_text("545\n")
    ctx = rep.Context(SPEC, rep.collect(SPEC, layout), layout)
    (text,) = rep.write_section(ctx, _kind("zoo_eval"))
    assert "took 9 min" in text and "| abm_clip | 60.0 (3/5) |" in text
    assert "(pick_block; 5 episodes per task and split)" in text
    assert "`abm zoo eval --tasks pick_block --episodes 5` reproduces it" in text
    # a gated edition (the third) names its models: before its gate they are not abm zoo eval's default
    v3 = load_spec("paper_tables_v3")
    (text,) = rep.write_section(rep.Context(v3, rep.collect(SPEC, layout), layout), _kind("zoo_eval"))
    assert "`abm zoo eval --tasks pick_block --episodes 5 --models abm_clip_v3 rvt_clip_v3` reproduces it" in text


def test_weakest_keyframes_ranks_kinds_by_their_median_error_over_tasks() -> None:
    def row(task: str, kind: str, cm: float) -> dict:
        return {"task": task, "split": "seen", "kind": kind, "position_cm_median": cm, "rotation_deg_median": 0.0}

    rows = [row("a", "grasp", 0.5), row("b", "grasp", 0.7), row("c", "grasp", 9.0),
            row("a", "move", 12.0), row("b", "move", 4.0), row("a", "pour", 30.0)]  # pour: one task only
    text = rep.weakest_keyframes({"abm_oracle": rows})
    assert "abm_oracle: move 8.0 cm, grasp 0.7 cm." in text
    assert rep.weakest_keyframes({"abm_oracle": rows}, "unseen") == ""


def test_approach_yaw_sets_the_approach_against_the_grasp_per_run() -> None:
    def row(task: str, kind: str, deg: float, split: str = "seen") -> dict:
        return {"task": task, "split": split, "kind": kind, "position_cm_median": 1.0, "rotation_deg_median": deg}

    rows = [row("place_food", "approach", 80.0), row("pick_block", "approach", 20.0),
            row("close_jar", "approach", 30.0), row("place_food", "grasp", 4.0), row("pick_block", "grasp", 6.0),
            row("close_jar", "move", 90.0), row("place_food", "approach", 10.0, "unseen")]
    text = rep.approach_yaw({"abm_oracle": rows, "rvt_clip": [row("a", "approach", 50.0)]})
    assert "abm_oracle 30° / 5° (place_food 80°)." in text  # medians over tasks; move and unseen left out
    assert "rvt_clip" not in text  # no grasp keyframe to compare with
    assert rep.approach_yaw({"abm_oracle": rows}, "unseen") == ""


def test_finished_results_are_kept_and_restored_into_a_fresh_out(tmp_path: Path) -> None:
    layout = _layout(tmp_path)
    _write_eval(layout, "rvt_clip", "seen", [_rate(t, "seen", [20.0, 40.0]) for t in TASKS])
    # stage times: this session's stamps plus the totals carried from sessions whose folders are gone
    layout.times.write_text("train_minutes 100\ntrain_start 0\ntrain_end 600\neval_start 600\n")
    assert stage_minutes(layout.times) == {"train": 110.0}
    layout.zoo_eval.mkdir(parents=True)
    (layout.zoo_eval / "results.md").write_text("| method |\n")  # still running: no seconds yet
    assert keep(SPEC, layout) == 3
    assert keep(SPEC, layout) == 0  # unchanged: nothing rewritten
    kept = layout.kept
    assert (kept / "rvt_clip_seen.json").is_file() and (kept / "zoo_eval.md").is_file()
    assert not (kept / "zoo_eval_seconds.txt").exists()
    # a fresh clone: nothing under OUT; the engine restores first, the report then has the row again
    fresh = Layout.of(SPEC, tmp_path, tmp_path / "fresh")
    assert restore(SPEC, fresh) == 3
    assert json.loads(fresh.eval_dir("rvt_clip", "seen").joinpath("results.json").read_text())[0]["mean"] == 30.0
    assert stage_minutes(fresh.times) == {"train": 110.0}
    assert _ctx(fresh).average("rvt_clip", "seen") == 30.0
    # what OUT has is never overwritten by an older kept copy
    (fresh.zoo_eval / "results.md").write_text("newer\n")
    assert restore(SPEC, fresh) == 0
    assert (fresh.zoo_eval / "results.md").read_text() == "newer\n"


def test_caveats_appear_only_for_runs_with_cells(tmp_path: Path) -> None:
    from dataclasses import replace

    runs = dict(SPEC.runs)
    runs["abm_clip"] = replace(runs["abm_clip"], caveat="Rerun pending.")
    runs["stack"] = replace(runs["stack"], caveat="Other.")
    spec = replace(SPEC, runs=runs)
    layout = _layout(tmp_path)
    assert rep.write_section(rep.Context(spec, rep.Outcomes(cells={}), layout), _kind("caveats")) == []
    cells = {("abm_clip", "close_jar", "seen"): _rate("close_jar", "seen", [50.0])}
    caveats = rep.write_section(rep.Context(spec, rep.Outcomes(cells=cells), layout), _kind("caveats"))
    assert caveats == ["Rerun pending."]
    text = rep.compose(spec, layout, rep.Outcomes(cells=cells)).summary
    assert "Rerun pending." in text and "Other." not in text


def test_links_are_rewritten_relative_to_the_document() -> None:
    text = "see [a](docs/results/x.md#top), [b](https://x.org/a), [c](#here) and [d](docs/results/paper_tables/)"
    assert rep.relink(text, "docs/results") == ("see [a](x.md#top), [b](https://x.org/a), [c](#here) and "
                                                "[d](paper_tables/)")
    assert rep.relink(text, ".") == text


def test_a_readme_without_the_block_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="has no <!-- paper-tables:start -->"):
        rep.replace_block("# readme\n", "paper-tables", "x\n")
    assert rep.replace_block("a\n<!-- b:start -->\nold\n<!-- b:end -->\nz", "b", "new\n") == \
        "a\n<!-- b:start -->\nnew\n<!-- b:end -->\nz"


# ----------------------------------------------------------------------------- the other experiments' reports
CLIP_SPEC = load_spec("clip_grounder")
KEPT_SPECS = ("seen_unseen", "clip_grounder", "rotation_probe")


@pytest.mark.parametrize("name", KEPT_SPECS)
def test_the_committed_blocks_regenerate_from_the_committed_outcomes(tmp_path: Path, name: str) -> None:
    """The README blocks and documents of the experiments without a zoo, from their kept outcomes alone."""
    spec = load_spec(name)
    root = tmp_path / "root"
    shutil.copytree(REPO / spec.kept, root / spec.kept)
    files = [f for f in (spec.report.readme, spec.report.document, "docs/results/grounding_quality.json") if f]
    for f in files:
        (root / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(REPO / f, root / f)
    if spec.clip:
        (root / spec.clip).parent.mkdir(parents=True, exist_ok=True)
        (root / spec.clip).symlink_to(REPO / spec.clip)
    assert Engine(spec, root=root).run(["report"]) == 0
    for f in files:
        assert (root / f).read_bytes() == (REPO / f).read_bytes(), f"{f} differs from its regeneration"
    for figure in spec.report.figures:  # drawn from the kept outcomes: the committed images (when drawn)
        if (REPO / figure.file).is_file():
            assert (root / figure.file).is_file(), figure.file


def _clip_layout(tmp_path: Path) -> Layout:
    return Layout.of(CLIP_SPEC, tmp_path, tmp_path / "out")


def _clip_ctx(layout: Layout) -> rep.Context:
    return rep.Context(CLIP_SPEC, rep.collect(CLIP_SPEC, layout), layout)


def _clip_section(kind: str):
    return next(s for s in (*CLIP_SPEC.report.summary, *CLIP_SPEC.report.details) if s.kind == kind)


def test_success_rows_name_runs_and_variants_and_leave_out_what_is_not_evaluated(tmp_path: Path) -> None:
    layout = _clip_layout(tmp_path)
    for split in ("seen", "unseen"):
        for run, rate in (("abm_oracle", [80.0, 100.0] if split == "seen" else [60.0, 80.0]),
                          ("abm_clip", [40.0, 60.0] if split == "seen" else [20.0, 20.0]), ("ifd_clip", [10.0, 0.0])):
            rates = [{**_rate(t, split, rate), "episodes": 20} for t in ("pick_block", "place_food")]
            _write_eval(layout, run, split, rates)
        _write_eval(layout, "abm_oracle@clip", split, [_rate(t, split, [30.0]) for t in ("pick_block", "place_food")])
    ctx = _clip_ctx(layout)
    title, table = rep.write_section(ctx, _clip_section("success_rows"))
    rows = [line.split(" | ")[0] for line in table.splitlines()[2:]]
    assert rows == ["| abm_oracle", "| abm_clip", "| ifd_clip", "| abm_oracle → CLIP"]  # rvt runs not evaluated
    assert "| abm_clip | abm | mask from the benchmark CLIP" in table and "18/20" in table
    assert table.splitlines()[3].endswith("| 50 | 20 | 0.40 |")
    assert "| abm_oracle → CLIP | abm | trained on oracle masks, grounded by the benchmark CLIP" in table
    (sentences,) = rep.write_section(ctx, _clip_section("sentences"))
    assert sentences.splitlines() == [
        "abm keeps 20 % / 70 % = 0.29 of the oracle's unseen success with the learned grounder (50 % / 90 % on seen "
        "objects).",
        "The oracle-trained policy grounded by CLIP only at evaluation reaches 30 % / 30 % (seen / unseen), the "
        "CLIP-trained one 50 % / 20 %."]  # no rvt sentence: rvt_hash and rvt_clip are not evaluated
    assert rep.write_section(ctx, _clip_section("missing")) == ["Not evaluated in this run: rvt_hash, rvt_clip."]


def test_grounding_quality_rows_of_the_evaluated_tasks(tmp_path: Path) -> None:
    layout = _clip_layout(tmp_path)
    record = {"config": "proposals (combined, no split)", "task": "pick_block", "split": "unseen", "iou": 0.81,
              "hit_rate": 0.9, "top1": 0.7, "n": 10}
    quality = {"records": [record, {**record, "config": "field (maskclip)", "iou": 0.1},
                           {**record, "task": "close_jar"}]}  # not a task of this experiment
    (tmp_path / "docs/results").mkdir(parents=True)
    (tmp_path / "docs/results/grounding_quality.json").write_text(json.dumps(quality))
    title, table = rep.write_section(_clip_ctx(layout), _clip_section("grounding_quality"))
    assert "`proposals (combined, no split)`" in title
    assert table.splitlines()[2:] == ["| pick_block | unseen | 10 | 0.81 | 90 % | 70 % |"]


def test_the_setup_states_what_the_spec_asks_in_its_order(tmp_path: Path) -> None:
    layout = _clip_layout(tmp_path)
    entries = [{"name": "abm_clip", "method": "abm", "steps": 20, "train_minutes": 2.0, "samples_per_s": 8.04,
                "recipe": {"preset": "small+custom", "resolution": 48, "patch_size": 6, "batch": 8,
                           "optimizer": "adamw", "lr": 0.001, "workspace_size": 0.6}}]
    cells = {("abm_clip", "pick_block", "seen"): {**_rate("pick_block", "seen", [50.0, 50.0, 50.0]), "episodes": 30}}
    ctx = rep.Context(CLIP_SPEC, rep.Outcomes(cells=cells, entries=entries, machines=["m1", "m2"]), layout)
    (text,) = rep.write_section(ctx, _clip_section("setup"))
    assert text.startswith("Machines (every session that ran a stage): m1; m2. Data: 20 seen demonstrations per task "
                           "(pick_block, place_food). CLIP: the benchmark CLIP in `models/benchmark-clip` (`abm clip "
                           "train`: trained on simulator renders")  # no folder here: its size is not stated
    assert ("Recipe (every model): `small+custom` preset at 48² views over a 0.6 m cube, patch 6, 20 steps of batch "
            "8, adamw lr 0.001, two trainings at a time with one thread each.") in text
    assert "Training minutes: abm_clip 2.0. Training samples/s: abm_clip 8.0." in text
    assert text.endswith("Evaluation: 10 seeded episodes × 3 repeats per task and split, at most 8 keyframes, the "
                         "same scenes for every model.")


def test_kept_run_summaries_come_from_the_run_folders_and_survive_them(tmp_path: Path) -> None:
    spec = load_spec("seen_unseen")
    layout = Layout.of(spec, tmp_path, tmp_path / "out")
    run = layout.run_dir("abm")
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({
        "train": {"tasks": None, "data": "runs/seen_unseen/data", "steps": 4000, "batch": 8, "optimizer": "adamw",
                  "warmup": 50, "weight_decay": 1e-4, "seed": 0, "language": {"kind": "hash"},
                  "policy": PolicyConfig.from_preset("small", "abm", resolution=64).to_dict()},
        "lr": 1e-3, "language": {"kind": "hash"}}))
    (run / "log.csv").write_text("step,total,translation,rotation,gripper,samples_per_s,elapsed_s\n" + "".join(
        f"{s},{9 / s},{5 / s},{3 / s},{1 / s},7.0,{s * 1.5}\n" for s in range(10, 4001, 10)))
    (entry,) = rep.kept_run_summaries(spec, layout)
    assert entry["minutes_at_steps"] == {"1000": 25.0, "2000": 50.0, "3000": 75.0}
    assert (entry["train_minutes"], entry["samples_per_s"], entry["label"]) == (100.0, 7.0, "abm")
    assert "workspace_size" not in entry["recipe"]  # the default cube is not stated
    rep.keep_training_log(run, layout.kept / "training_abm.csv")
    kept = (layout.kept / "training_abm.csv").read_text().splitlines()
    assert kept[0] == "step,total,translation,rotation,gripper" and kept[-1].startswith("4000,")
    assert len(kept) < 260  # at most ~200 rows and the last one
