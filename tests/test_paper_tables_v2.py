"""The paper tables' second edition as the engine sees it (spec paper_tables_v2, recipe paper_tables_v2): the spec
loads with the first edition's runs plus a second seed, its recipe adds the rotation crop, a dry run and the status
work on a clone with nothing under runs/, the diagnosis runs the skill-text probe, its models and carry stay apart
from the first edition's, and the evaluation records what the diagnosis reads (failure reasons, a random yaw's
error)."""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from abm.cli import main
from abm.configuration import load_recipe
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.experiments.jobs import DiagnoseJob, EvaluationJob
from abm.experiments.spec import SpecError, builtin_specs, load_spec, parse_spec
from abm.experiments.stages import BLOCKED, DONE, LEFT, Engine, training_steps
from abm.experiments.state import Layout, carry_unfinished, restore_training
from abm.policy.checkpoint import save_checkpoint
from abm.policy.config import PolicyConfig

REPO = Path(__file__).resolve().parents[1]
V1, V2 = load_spec("paper_tables"), load_spec("paper_tables_v2")


def _clone(tmp_path: Path) -> Path:
    """A root like a fresh clone: the zoo (its index, the benchmark CLIP linked), nothing under runs/."""
    root = tmp_path / "clone"
    (root / "models").mkdir(parents=True)
    shutil.copyfile(REPO / "models/index.json", root / "models/index.json")
    (root / "models/benchmark-clip").symlink_to(REPO / "models/benchmark-clip")
    return root


def test_the_second_edition_has_the_first_editions_runs_data_and_tasks_plus_second_seeds() -> None:
    assert list(V2.runs) == [*V1.runs, "abm_clip_hash_seed1", "concat-rerendered_seed1"]
    for name, run in V1.runs.items():  # the same runs, trained for longer with the zoom and the rotation crop
        assert replace(V2.runs[name].config, steps=run.config.steps, policy=run.config.policy) == run.config
        assert (V2.runs[name].label, V2.runs[name].grounding) == (run.label, run.grounding)
    for run in ("abm_clip_hash", "concat-rerendered"):  # center-pixel and the best fusion, seed 1
        assert V2.runs[f"{run}_seed1"].config == replace(V2.runs[run].config, seed=1)
    assert (V2.data, V2.training.tasks, V2.split_tasks()) == (V1.data, V1.training.tasks, V1.split_tasks())
    ev = V2.evaluation
    assert (ev.episodes, ev.repeats, ev.from_zoo, ev.zoo_eval) == (25, 3, True, ("abm_clip", "rvt_clip"))
    assert next(s for s in ev.splits if s.split == "compositional").runs == next(
        s for s in V1.evaluation.splits if s.split == "compositional").runs
    assert V2.training_order() == ["abm_clip", "rvt_clip", "abm_oracle", "ifd_clip", "abm_clip_hash", "stack",
                                   "concat-rerendered", "concat-full", "abm_clip_hash_seed1",
                                   "concat-rerendered_seed1"]
    assert (V2.out, V2.kept, V2.zoo, V2.zoo_suffix, V2.edition) == ("runs/paper_v2", "docs/results/paper_tables_v2",
                                                                     "models", "_v2", 2)
    # the README's block was this edition's until the third edition's gate opened (paper_tables_v3.yaml)
    assert (V2.report.readme, V2.report.block, V1.report.readme) == ("", "", "")
    probe = V2.diagnose.skill_text
    assert (probe.tasks, probe.kind, probe.within_cm) == (("place_wine", "pick_block"), "move", 5.0)
    assert "rvt_clip" not in probe.runs and "ifd_clip" not in probe.runs
    assert {"abm_clip_hash_seed1", "concat-rerendered_seed1"} <= set(probe.runs)


def test_the_recipe_is_the_first_editions_plus_the_zoom_and_the_rotation_crop(tmp_path: Path) -> None:
    v1, v2 = load_recipe("paper_tables"), load_recipe("paper_tables_v2")
    assert v2["policy"] == {**v1["policy"], "zoom_size": 0.3, "zoom_resolution": 32, "zoom_patch_size": 4,
                            "rotation_crop": 16}
    assert {k: v for k, v in v2.items() if k not in ("policy", "steps")} == {
        k: v for k, v in v1.items() if k not in ("policy", "steps")}
    assert v2["steps"] == 6000 and V2.training.steps is None  # the budget: one line of the recipe
    assert training_steps(V2) == 6000
    engine = Engine(V2, root=_clone(tmp_path))
    recipe = engine.recipe("abm_clip_hash_seed1")
    assert (recipe["steps"], recipe["seed"], recipe["method"], recipe["language"]) == (6000, 1, "abm", "hash")
    assert recipe["policy"]["rotation_crop"] == 16 and recipe["policy"]["zoom_size"] == 0.3
    assert recipe["data"] == "runs/paper_v2/data"
    assert recipe["cache_dir"] == "runs/paper_v2/cache_masks"
    assert engine.recipe("abm_clip_hash")["seed"] == 0  # the recipe's default seed, like the first edition


def test_a_dry_run_and_the_status_work_on_a_clone_with_nothing_under_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = _clone(tmp_path)
    assert main(["experiment", "run", "paper_tables_v2", "--root", str(root), "--dry-run"]) == 0
    captured = capsys.readouterr()
    logged = captured.out + captured.err  # the engine logs its plan (abm's logger writes to stderr)
    assert not (root / "runs").exists()  # a dry run writes nothing
    assert "data generate --task close_jar,insert_peg" in logged and "--episodes 20 --out runs/paper_v2/data" in logged
    for job in ("train/abm_clip:", "train/abm_clip_hash_seed1:", "export/abm_clip: skipped (not trained yet)",
                "eval/abm_clip/seen: skipped (not exported yet)", "eval/zoo: skipped (waits for abm_clip, rvt_clip",
                "diagnose/abm_clip@oracle: skipped", "diagnose/skill_text/abm_clip/place_wine: skipped",
                "report: would write docs/results/paper_tables_v2.md"):
        assert job in logged, job
    assert logged.index("train/abm_clip:") < logged.index("train/rvt_clip:") < logged.index("train/abm_oracle:")
    assert main(["experiment", "status", "paper_tables_v2", "--root", str(root)]) == 0
    out = capsys.readouterr().out
    assert "diagnose/skill_text/concat-full/pick_block" in out and "eval/abm_clip_hash_seed1/unseen" in out
    assert "eval/stack/compositional" not in out  # Table 2 has the Table-1 runs only


def test_the_diagnosis_probes_the_skill_text_of_the_exported_models(tmp_path: Path) -> None:
    root = _clone(tmp_path)
    engine = Engine(V2, root=root)
    probes = {j.id: j for j in engine.plan("diagnose") if "/skill_text/" in j.id}
    assert len(probes) == 2 * 8 and all(j.state == BLOCKED and j.note == "not exported yet" for j in probes.values())
    # exported under its second-edition name (the committed model: the index entry checks its bytes)
    (root / "models/abm_oracle_v2.pt").symlink_to(REPO / "models/abm_oracle_v2.pt")
    assert {j.id: j.state for j in engine.plan("export")}["export/abm_oracle"] == DONE
    job = {j.id: j for j in engine.plan("diagnose")}["diagnose/skill_text/abm_oracle/pick_block"]
    assert job.state == LEFT
    assert job.work == DiagnoseJob(SkillTextProbe(
        model=Path("models/abm_oracle_v2.pt"), task="pick_block", keyframe="move", split="seen", episodes=5,
        resolution=128, skill_tasks=tuple(V2.data.tasks),
        out=Path("runs/paper_v2/skill_text/abm_oracle_pick_block.json")))
    ev = {j.id: j for j in engine.plan("eval")}["eval/abm_oracle/seen"].work
    assert isinstance(ev, EvaluationJob)
    assert list(ev.request.runs) == [Path("models/abm_oracle_v2.pt")] and ev.request.repeats == 3
    # a probe kept under the committed folder counts as done on a fresh clone
    kept = root / V2.kept / "skill_text_abm_oracle_pick_block.json"
    kept.parent.mkdir(parents=True)
    kept.write_text("{}")
    assert {j.id: j.state for j in Engine(V2, root=root).plan("diagnose")}[
        "diagnose/skill_text/abm_oracle/pick_block"] == DONE


def _touch(layout: Layout, run: str, step: int) -> None:
    folder = layout.run_dir(run) / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    save_checkpoint(folder / f"step_{step:08d}.pt", {"step": step, "out": layout.out.name})


def test_the_two_editions_carry_their_runs_apart(tmp_path: Path) -> None:
    v1, v2 = Layout.of(V1, tmp_path), Layout.of(V2, tmp_path)
    _touch(v1, "abm_clip", 500)
    _touch(v2, "abm_clip", 250)
    assert carry_unfinished(V1, v1) == ["abm_clip"] and carry_unfinished(V2, v2) == ["abm_clip"]
    assert (tmp_path / "models/carry/abm_clip/step_00000500.pt").is_file()
    assert (tmp_path / "models/carry/paper_tables_v2/abm_clip/step_00000250.pt").is_file()
    # fresh clones: each edition continues from its own checkpoint
    for spec, step in ((V1, 500), (V2, 250)):
        fresh = Layout.of(spec, tmp_path, tmp_path / f"fresh_{spec.name}")
        assert restore_training(fresh, "abm_clip")
        assert [p.name for p in (fresh.run_dir("abm_clip") / "checkpoints").iterdir()] == [f"step_{step:08d}.pt"]


def test_no_two_builtin_specs_share_a_zoo_file_or_a_carried_run() -> None:
    """Specs exporting into one zoo use distinct model names, and their carries never hold the same run folder
    (a carry inside another spec's carry is named after no run of that spec)."""
    specs = [load_spec(n) for n in builtin_specs()]
    files: dict[Path, str] = {}
    carried: dict[Path, str] = {}
    for spec in specs:
        layout = Layout.of(spec, Path("checkout"))
        for run in spec.runs:
            if layout.zoo is not None:
                assert files.setdefault(layout.zoo_file(run), spec.name) == spec.name, layout.zoo_file(run)
            if layout.carry is not None:
                for folder in (layout.carry / run, layout.carry / "eval" / run):
                    assert carried.setdefault(folder, spec.name) == spec.name, folder
    assert files[Path("checkout", "models", "abm_clip_v2.pt")] == "paper_tables_v2"
    assert files[Path("checkout", "models", "abm_clip.pt")] == "paper_tables"


@pytest.mark.parametrize("changes, message", [
    ({"edition": 2, "zoo_suffix": ""}, r"zoo_suffix: a later edition needs a zoo_suffix"),
    ({"zoo_suffix": "/v2"}, r"zoo_suffix: expected letters, digits"),
    ({"diagnose": {"skill_text": {"tasks": ["place_wine"], "runs": ["rvt_clip"]}}},
     r"diagnose\.skill_text\.runs: 'rvt_clip' is no run of this spec that reads a skill text"),
    ({"diagnose": {"skill_text": {"tasks": ["place_wine"], "within_cm": 0}}}, r"within_cm: expected a distance > 0"),
    ({"report": {"title": "t", "document": "d.md", "summary": [{"kind": "seeds", "of_table": 3,
                                                                "seeds": {"abm_clip_hash": "ghost"}}]}},
     r"report\.summary\[0\]\.seeds\.abm_clip_hash: expected two different runs of this spec"),
    ({"report": {"title": "t", "document": "d.md", "summary": [{"kind": "seeds", "of_table": 3}]}},
     r"report\.summary\[0\]\.seeds: a 'seeds' section needs seeds"),
])
def test_a_mistake_in_the_new_spec_fields_names_the_key(changes: dict, message: str) -> None:
    data = yaml.safe_load(V2.path.read_text())
    data.update(changes)
    with pytest.raises(SpecError, match=message):
        parse_spec(data, Path("v2.yaml"))


# ------------------------------------------------------------------------------------ what the evaluation keeps
def test_results_count_the_failure_reasons_per_task_and_split(tmp_path: Path) -> None:
    from abm.evaluation.results import EpisodeOutcome, aggregate, write_json

    def outcome(episode: int, success: bool, failure: str, task: str = "pick_block") -> EpisodeOutcome:
        return EpisodeOutcome("abm", task, "seen", episode % 2, episode, 1000 + episode, success, failure=failure)

    outcomes = [outcome(0, True, ""), outcome(1, False, "timeout"), outcome(2, False, "grasp missed"),
                outcome(3, False, "grasp missed"), outcome(4, False, ""),  # a log from before the reasons
                outcome(5, False, "crashed"), outcome(0, True, "", task="close_jar")]
    pick_block, close_jar = sorted(aggregate(outcomes), key=lambda r: r.task, reverse=True)
    assert pick_block.failures == {"crashed": 1, "grasp missed": 2, "timeout": 1, "unknown": 1}
    assert list(pick_block.failures) == ["crashed", "grasp missed", "timeout", "unknown"]  # FAILURES order
    assert close_jar.failures == {}
    write_json([pick_block], tmp_path / "results.json")
    assert json.loads((tmp_path / "results.json").read_text())[0]["failures"]["grasp missed"] == 2


def test_the_keyframe_summary_carries_a_random_yaws_error_for_each_symmetry() -> None:
    from abm.evaluation.keyframe_accuracy import KeyframeDeviation, summarise, yaw_chance_deg

    assert (yaw_chance_deg(2), yaw_chance_deg(4), yaw_chance_deg(0), yaw_chance_deg(1)) == (45.0, 22.5, 0.0, 90.0)

    def deviation(kind: str, symmetry: int) -> KeyframeDeviation:
        return KeyframeDeviation("abm", "place_food", "seen", 1, 0, kind, 1.0, 30.0, True, symmetry)

    rows = {r["kind"]: r for r in summarise([deviation("approach", 2), deviation("grasp", 4), deviation("grasp", 4),
                                             deviation("grasp", 2), deviation("lift", 0)])}
    assert (rows["approach"]["yaw_chance_deg"], rows["grasp"]["yaw_chance_deg"], rows["lift"]["yaw_chance_deg"]) == (
        45.0, 22.5, 0.0)


def test_a_two_stage_run_is_described_with_its_zoom_and_its_kept_curve_averages_the_batches(tmp_path: Path) -> None:
    from abm.experiments import report as rep

    layout = Layout.of(V2, tmp_path, tmp_path / "out")
    run = layout.run_dir("abm_clip")
    run.mkdir(parents=True)
    recipe = load_recipe("paper_tables_v2")
    (run / "config.json").write_text(json.dumps({
        "train": {"tasks": list(V2.data.tasks), "data": "runs/paper_v2/data", "steps": 6000, "batch": 8,
                  "optimizer": "adamw", "warmup": 50, "weight_decay": 1e-4, "seed": 0, "grounder": {"kind": "clip"},
                  "policy": PolicyConfig.from_preset("small", "abm", **recipe["policy"]).to_dict()},
        "lr": 1e-3, "language": {"kind": "clip"}}))
    # the logged losses cycle through three batches' values: the kept curve shows their mean
    header = "step,total,translation,rotation,gripper,collision,samples_per_s,elapsed_s,zoom_translation\n"
    (run / "log.csv").write_text(header + "".join(
        f"{s},{4 + (s // 10) % 3},1,{1 + (s // 10) % 3},0,0,8.0,{s},0.5\n" for s in range(10, 6001, 10)))
    entry = rep.describe_run(run)
    assert entry["recipe"]["zoom_size"] == 0.3 and entry["recipe"]["zoom_resolution"] == 32
    assert entry["recipe"]["zoom_patch_size"] == 4 and entry["recipe"]["rotation_crop"] == 16
    rep.keep_training_log(run, layout.kept / "training_abm_clip.csv")
    with (layout.kept / "training_abm_clip.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["step", "total", "translation", "rotation", "gripper", "zoom_translation"]
    assert len(rows) == 200 and rows[-1]["step"] == "6000"
    assert {r["total"] for r in rows} == {"5"} and {r["rotation"] for r in rows} == {"2"}  # 3 rows a window
    assert {r["zoom_translation"] for r in rows} == {"0.5"}
