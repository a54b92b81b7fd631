"""The experiment engine (abm.experiments): specs load and fail with the file and key, stages plan what is left
from the files on disk, the scheduler runs N commands at a time × T threads, unfinished work is carried across
machines, and ``abm experiment run|status|list`` drive it."""

from __future__ import annotations

import json
import shutil
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

import pytest
import yaml

from abm.cli import main
from abm.errors import ConfigError
from abm.evaluation.results import EpisodeOutcome
from abm.experiments import scheduler
from abm.experiments.jobs import DataJob, EvaluationJob, ExportJob, TrainJob, read_job
from abm.experiments.scheduler import Command, LocalRunner, RayRunner, Source
from abm.experiments.spec import SpecError, builtin_specs, load_spec, parse_spec
from abm.experiments.stages import BLOCKED, DONE, LEFT, Engine
from abm.experiments.state import (
    Layout,
    carry_unfinished,
    checkpoint_step,
    restore_evaluation,
    restore_training,
    span_minutes,
)
from abm.files import sha256_file
from abm.policy.checkpoint import save_checkpoint
from abm.zoo import ZooError

TINY: dict = {
    "name": "tiny",
    "out": "runs/tiny",
    "kept": "docs/results/tiny",
    "zoo": "models",
    "carry": "models/carry",
    "clip": "models/benchmark-clip",
    "tasks": {"two": ["pick_block", "place_food"]},
    "data": {"tasks": "two", "episodes": 1, "workers": 1, "resolution": 64},
    "training": {"recipe": "quickstart", "tasks": "two", "steps": 3, "train": {"batch": 2, "checkpoint_every": 3},
                 "policy": {"resolution": 32, "patch_size": 8}},
    "runs": {"abm_oracle": {"label": "ABM, oracle mask", "train": {"method": "abm", "grounder": "oracle"}},
             "rvt_clip": {"label": "RVT (CLIP text)", "train": {"method": "rvt", "language": "clip"}}},
    "evaluation": {"from_zoo": True, "episodes": 1, "repeats": 1, "workers": 1, "max_steps": 2,
                   "splits": {"seen": {"tasks": "two"}}},
    "resources": {"trainings_at_a_time": 2, "threads_each": 1},
    "report": {"title": "Tiny", "document": "docs/results/tiny.md", "records": "docs/results/tiny.json",
               "summary": [{"kind": "setup"}, {"kind": "per_task", "table": 1, "runs": ["abm_oracle", "rvt_clip"],
                                                "splits": ["seen"], "title": "Success:"}]},
}


def _spec(tmp_path: Path, data: dict | None = None, name: str = "tiny.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data or TINY, sort_keys=False, allow_unicode=True))
    return load_spec(path), path


def _with(**changes) -> dict:
    data = json.loads(json.dumps(TINY))
    for dotted, value in changes.items():
        node = data
        *parents, last = dotted.split("__")
        for key in parents:
            node = node[key]
        node[last] = value
    return data


def test_every_builtin_spec_loads() -> None:
    names = builtin_specs()
    assert {"paper_tables", "seen_unseen", "clip_grounder", "put_in_container", "rotation_probe"} <= set(names)
    for name in names:
        spec = load_spec(name)
        assert spec.runs and (spec.evaluation.splits or spec.diagnose or spec.finished) and (
            spec.report.document or spec.report.readme)
    paper = load_spec("paper_tables")
    assert paper.evaluation.episodes == 25 and paper.evaluation.repeats == 2 and paper.resources.threads_each == 1
    config = paper.runs["abm_clip_hash"].config  # the recipe with the spec's overrides and its CLIP, typed
    assert (config.method, config.grounder.kind, config.language_config.kind, config.steps) == ("abm", "clip", "hash",
                                                                                                5000)
    assert config.grounder.clip_options() == {"model": "models/benchmark-clip"} and config.lr == 1e-3
    assert (config.policy.resolution, config.policy.patch_size, config.policy.preset) == (64, 8, "small+custom")
    assert paper.runs["ifd_clip"].cache == "features" and paper.runs["stack"].cache == "masks"
    assert paper.runs["abm_oracle"].cache is None and not paper.runs["abm_oracle"].needs_clip
    assert paper.training_order()[0] == "abm_oracle" and paper.run_names()[0] == "rvt_clip"


@pytest.mark.parametrize("changes, message", [
    ({"data__episodes": "many"}, r"data\.episodes: expected a whole number from 1 to 1000000, got 'many' \(the "
                                 r"same check as abm data generate --episodes\)"),
    ({"data__episodes": 10**30}, r"data\.episodes: expected a whole number from 1 to 1000000, got "),
    ({"data__seed": 2**70}, r"data\.seed: expected a whole number from 0 to 4294967295, got "),
    ({"data__tasks": ["pick_block", "juggle"]}, r"data\.tasks: 'juggle' is no task of the benchmark \(known: "),
    ({"evaluation__splits": {"seen": {"tasks": ["juggle"]}}}, r"evaluation\.splits\.seen\.tasks: 'juggle' is no task"),
    ({"evaluation__repeats": 5000}, r"evaluation\.repeats: expected a whole number from 1 to 1000, got '5000' \(the "
                                    r"same check as abm eval --repeats\)"),
    ({"out": ""}, r"out: '' is the root itself \(the checkout\): give a folder inside it"),
    ({"out": "."}, r"out: '\.' is the root itself"),
    ({"out": "../elsewhere"}, r"out: '\.\./elsewhere' leaves the root: give a path relative to the root"),
    ({"kept": "/srv/kept"}, r"kept: '/srv/kept' leaves the root"),
    ({"carry": "models/../../carry"}, r"carry: 'models/\.\./\.\./carry' leaves the root"),
    ({"data__folder": "/data"}, r"data\.folder: '/data' leaves the root"),
    ({"report__document": "../README.md"}, r"report\.document: '\.\./README\.md' leaves the root"),
    ({"report__figures": [{"kind": "success", "file": "docs/x.md", "alt": "x"}]},
     r"report\.figures\[0\]\.file: expected a PNG file"),
    ({"data__tasks": "three"}, r"data\.tasks: 'three' is no task list of this spec"),
    ({"evaluation__repeat": 2}, r"evaluation: unknown keys \['repeat'\] \(expected: \['device', 'episodes', "),
    ({"runs__abm_oracle__train": {"method": "abm", "stepz": 3}}, r"runs\.abm_oracle\.train: unknown keys \['stepz'\] "
                                                                  r"\(expected: \['accept_changed_config', "),
    ({"runs__abm_oracle__train": {"method": "abm", "batch": 0}},
     r"runs\.abm_oracle\.train\.batch: expected a whole number from 1 to 1000000000, got '0'"),
    ({"runs__abm_oracle__train": {"method": "abm", "out": "x"}}, r"runs\.abm_oracle\.train\.out: is set by the engine"),
    ({"runs__abm_oracle__policy": {"resolution": "big"}},
     r"runs\.abm_oracle\.policy\.resolution: expected a whole number, got 'big'"),
    ({"runs__abm_oracle__policy": {"workspace_center": [0.5, 0]}},
     r"runs\.abm_oracle\.policy\.workspace_center: expected a list of 3 values, got \[0\.5, 0\]"),
    ({"runs__abm_oracle__train": {"grounder": "oracle"}}, r"runs\.abm_oracle\.train: needs a method"),
    ({"clip": ""}, r"clip: runs need the benchmark CLIP"),
    ({"report__summary": [{"kind": "per_task", "runs": ["nope"]}]}, r"report\.summary\[0\]\.runs: 'nope' is no run"),
    ({"report__summary": [{"kind": "setup", "title": "x"}]},
     r"report\.summary\[0\]\.title: a 'setup' section takes show"),
    ({"report__summary": [{"kind": "tables"}]}, r"report\.summary\[0\]\.kind: expected one of setup, "),
    ({"evaluation__splits": {"seen": {"tasks": "two", "runs": ["ghost"]}}}, r"evaluation\.splits\.seen\.runs: 'ghost'"),
    ({"resources__order": ["ghost"]}, r"resources\.order: 'ghost' is no run"),
    ({"report__summary": [{"kind": "setup", "show": ["weather"]}]},
     r"report\.summary\[0\]\.show: 'weather' is not something a setup states"),
    ({"report__summary": [{"kind": "sentences", "sentences": [{"text": "x", "runs": ["abm_oracle"]}]}]},
     r"report\.summary\[0\]\.sentences\[0\]\.runs: expected two runs of this spec"),
    ({"report__document": "", "report__title": ""}, r"report\.document: writes nothing"),
    ({"evaluation__variants": {"abm_oracle@tracking": {"run": "abm_oracle", "grounder": "clip"}}},
     r"evaluation\.variants: a variant is named RUN@GROUNDER \(abm_oracle@clip\)"),
])
def test_a_spec_mistake_names_the_file_and_the_key(tmp_path: Path, changes: dict, message: str) -> None:
    with pytest.raises(SpecError, match=r"tiny\.yaml: " + message):
        _spec(tmp_path, _with(**changes))


def test_a_duplicate_key_or_a_missing_spec_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text("name: a\nname: b\n")
    with pytest.raises(SpecError, match="dup.yaml: the key 'name' appears twice"):
        load_spec(path)
    with pytest.raises(ConfigError, match="built-in experiment spec: .*paper_tables"):
        load_spec("no_such_spec")
    with pytest.raises(SpecError, match=r"x\.yaml: expected a mapping, got \[1, 2\]"):
        parse_spec([1, 2], Path("x.yaml"))


def _touch_checkpoint(layout: Layout, run: str, step: int) -> None:
    folder = layout.run_dir(run) / "checkpoints"
    folder.mkdir(parents=True, exist_ok=True)
    save_checkpoint(folder / f"step_{step:08d}.pt", {"step": step})  # a sealed checkpoint holding its step


def _states(jobs) -> dict[str, str]:
    return {j.id: j.state for j in jobs}


def test_stages_plan_what_is_left_from_the_files_on_disk(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)
    engine = Engine(spec, root=tmp_path)
    layout = engine.layout
    (data,) = engine.plan("data")
    assert data.state == LEFT and data.note == "0/2 demonstrations"
    assert data.work == DataJob(("pick_block", "place_food"), "seen", 1, Path("runs/tiny/data"), workers=1,
                                resolution=64)
    train = {j.id: j for j in engine.plan("train")}
    assert train["train/abm_oracle"].state == LEFT and train["train/abm_oracle"].threads == 1
    assert train["train/rvt_clip"].state == BLOCKED and "no benchmark CLIP" in train["train/rvt_clip"].note
    work = train["train/abm_oracle"].work  # its typed config: the spec's run, the engine's run folder, resumed
    assert isinstance(work, TrainJob) and work.recipe == Path("runs/tiny/recipes/abm_oracle.yaml")
    assert (work.config.out, work.config.resume, work.config.progress) == (Path("runs/tiny/abm_oracle"), True, False)
    assert (work.config.steps, work.config.batch, work.config.data) == (3, 2, Path("runs/tiny/data"))
    recipe = engine.recipe("abm_oracle")  # the recipe file, the common and the run's overrides, the engine's paths
    assert (recipe["steps"], recipe["batch"], recipe["method"], recipe["data"]) == (3, 2, "abm", "runs/tiny/data")
    assert recipe["policy"]["resolution"] == 32 and recipe["policy"]["workspace_size"] == 0.6  # quickstart's cube
    assert recipe["tasks"] == ["pick_block", "place_food"] and "clip_model" not in recipe
    assert engine.recipe("rvt_clip")["clip_model"] == "models/benchmark-clip"
    assert _states(engine.plan("export")) == {"export/abm_oracle": BLOCKED, "export/rvt_clip": BLOCKED}
    assert _states(engine.plan("eval"))["eval/abm_oracle/seen"] == BLOCKED
    _touch_checkpoint(layout, "abm_oracle", 2)
    assert _states(engine.plan("train"))["train/abm_oracle"] == LEFT  # step 2 of 3: not finished
    _touch_checkpoint(layout, "abm_oracle", 3)
    assert _states(engine.plan("train"))["train/abm_oracle"] == DONE
    (export,) = [j for j in engine.plan("export") if j.id == "export/abm_oracle"]
    assert export.state == LEFT and export.work == ExportJob(Path("runs/tiny/abm_oracle"), Path("models/abm_oracle.pt"),
                                                             "bfloat16")
    (tmp_path / "models").mkdir()
    (tmp_path / "models/abm_oracle.pt").write_bytes(b"model")
    (ev,) = [j for j in engine.plan("eval") if j.id == "eval/abm_oracle/seen"]
    assert ev.state == LEFT and ev.work.request.runs == (Path("models/abm_oracle.pt"),)
    assert (ev.work.request.tasks, ev.work.request.splits, ev.work.request.out) == (
        ("pick_block", "place_food"), ("seen",), Path("runs/tiny/eval/abm_oracle/seen"))
    # a committed result counts as done before it is restored (status on a fresh clone)
    (tmp_path / "docs/results/tiny").mkdir(parents=True)
    (tmp_path / "docs/results/tiny/abm_oracle_seen.json").write_text("[]")
    assert _states(engine.plan("eval"))["eval/abm_oracle/seen"] == DONE
    # --runs: only those runs
    assert list(_states(Engine(spec, root=tmp_path, runs=["rvt_clip"]).plan("train"))) == ["train/rvt_clip"]
    with pytest.raises(ValueError, match="--runs ghost: not a run of tiny"):
        Engine(spec, root=tmp_path, runs=["ghost"])


class FakeRunner:
    """Runs nothing: records the commands and makes the files each job would write."""

    def __init__(self, engine_root: Path, fail: str = "", stop: str = "") -> None:
        self.root, self.fail, self.stop, self.ran = engine_root, fail, stop, []

    def run(self, commands, source, slots, on_start=None):
        codes = {}
        for cmd in commands:
            if cmd.before:
                cmd.before()
            if on_start:
                on_start(cmd, None)
            if cmd.job == self.stop:
                raise KeyboardInterrupt  # Ctrl-C or SIGTERM while the job runs
            self.ran.append(cmd.job)
            if cmd.job.startswith("train/") and cmd.job != self.fail:
                out = self.root / cmd.work.config.out / "checkpoints"
                out.mkdir(parents=True, exist_ok=True)
                save_checkpoint(out / "step_00000003.pt", {"step": 3})
            elif cmd.job.startswith("eval/"):
                for request in (cmd.work.request, *getattr(cmd.work, "together", ())):  # a split's models at once
                    out = self.root / request.out
                    out.mkdir(parents=True, exist_ok=True)
                    (out / "results.json").write_text(json.dumps([{
                        "method": "abm", "task": request.tasks[0], "split": "seen", "per_repeat": [100.0],
                        "episodes": 1, "errors": 0, "mean": 100.0, "std": 0.0}]))
            codes[cmd.job] = 1 if cmd.job == self.fail else 0
            if cmd.job == self.fail:  # what a failing command writes last: its one error line, then a blank
                cmd.log.parent.mkdir(parents=True, exist_ok=True)
                cmd.log.write_text("step 1/3\n  0%|          | 0/3\r 33%|███       | 1/3\n"
                                   "abm: error: --data runs/x/data: no episodes\n\n")
            if cmd.after:
                cmd.after(codes[cmd.job])
        return codes


def _one_run() -> dict:
    """The tiny spec with its oracle run only (no CLIP needed)."""
    data = _with(runs={"abm_oracle": TINY["runs"]["abm_oracle"]},
                 report__summary=[{"kind": "setup"},
                                  {"kind": "per_task", "table": 1, "runs": ["abm_oracle"], "splits": ["seen"]}])
    data.pop("clip")
    return data


def test_a_run_does_what_is_left_and_a_rerun_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    spec, _ = _spec(tmp_path, _one_run())
    (tmp_path / "README.md").write_text("x")
    runner = FakeRunner(tmp_path)
    engine = Engine(spec, root=tmp_path, runner=runner)

    def fake_local(self, commands, source, slots, on_start=None):  # data, ground, export: make their files
        for cmd in commands:
            if cmd.before:
                cmd.before()
            if cmd.job == "export/abm_oracle":
                (tmp_path / "models").mkdir(exist_ok=True)
                (tmp_path / "models/abm_oracle.pt").write_bytes(b"model")
            runner.ran.append(cmd.job)
            if cmd.after:
                cmd.after(0)
        return {cmd.job: 0 for cmd in commands}

    monkeypatch.setattr(LocalRunner, "run", fake_local)
    assert engine.run(["data", "train", "export", "eval", "report"]) == 0
    assert runner.ran == ["data", "train/abm_oracle", "export/abm_oracle", "eval/abm_oracle/seen"]
    text = (tmp_path / "docs/results/tiny.md").read_text()
    assert "| pick_block | 100 (1/1) |" in text and "Machine (every session that ran a stage): " in text
    assert json.loads((tmp_path / "models/index.json").read_text())[0]["name"] == "abm_oracle"
    assert (tmp_path / "docs/results/tiny/abm_oracle_seen.json").is_file()  # kept for a fresh clone
    times = (tmp_path / "runs/tiny/times.txt").read_text().split()
    # the export ran as its training ended (inside the train stage): the export stage found nothing left
    assert times[0::3] == ["data_start", "data_end", "train_start", "train_end", "eval_start", "eval_end"]
    runner.ran.clear()
    assert Engine(spec, root=tmp_path, runner=runner).run(["data", "train", "export", "eval", "report"]) == 0
    assert runner.ran == []  # everything is done: nothing runs twice
    status = {j.id: j for j in Engine(spec, root=tmp_path).status()}
    assert status["eval/abm_oracle/seen"].state == DONE and status["eval/abm_oracle/seen"].minutes is not None


def _two_oracle_runs() -> dict:
    """The tiny spec with two oracle runs (no CLIP needed)."""
    data = _one_run()
    data["runs"]["abm_oracle_seed1"] = {"label": "ABM, oracle mask, seed 1",
                                        "train": {"method": "abm", "grounder": "oracle", "seed": 1}}
    return data


def _fake_export(tmp_path: Path, ran: list[str]):
    def run(self, commands, source, slots, on_start=None):  # abm export: writes the zoo file
        for cmd in commands:
            if on_start:
                on_start(cmd, None)
            target = tmp_path / cmd.work.out
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(b"model")
            ran.append(cmd.job)
            if cmd.after:
                cmd.after(0)
        return {cmd.job: 0 for cmd in commands}
    return run


def test_a_splits_evaluations_run_as_one_job_each_into_its_own_folder(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    spec, _ = _spec(tmp_path, _two_oracle_runs())
    runner = FakeRunner(tmp_path)
    monkeypatch.setattr(LocalRunner, "run", _fake_export(tmp_path, runner.ran))
    assert Engine(spec, root=tmp_path, runner=runner).run(["train", "export"]) == 0
    runner.ran.clear()
    engine = Engine(spec, root=tmp_path, runner=runner)
    planned = [j.id for j in engine.plan("eval")]
    assert planned == ["eval/abm_oracle/seen", "eval/abm_oracle_seed1/seen"]  # status and carry stay per model
    assert engine.run(["eval"]) == 0
    assert runner.ran == ["eval/abm_oracle/seen"]  # one process: every scene built once for both models
    job = read_job(Layout.of(spec, tmp_path).job_file("eval/abm_oracle/seen"))
    assert isinstance(job, EvaluationJob) and job.command() is None
    assert [r.out.as_posix() for r in (job.request, *job.together)] == [
        "runs/tiny/eval/abm_oracle/seen", "runs/tiny/eval/abm_oracle_seed1/seen"]
    assert {j.id: j.state for j in Engine(spec, root=tmp_path).plan("eval")} == {
        "eval/abm_oracle/seen": DONE, "eval/abm_oracle_seed1/seen": DONE}
    runner.ran.clear()
    assert Engine(spec, root=tmp_path, runner=runner).run(["eval"]) == 0 and runner.ran == []
    alone = EvaluationJob(job.request)
    assert EvaluationJob.from_dict(job.to_dict()) == job and alone.command()[0] == "eval"


def test_each_training_is_exported_as_soon_as_it_ends(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    spec, _ = _spec(tmp_path, _two_oracle_runs())
    runner = FakeRunner(tmp_path)
    monkeypatch.setattr(LocalRunner, "run", _fake_export(tmp_path, runner.ran))
    assert Engine(spec, root=tmp_path, runner=runner).run(["train", "export"]) == 0
    # the first model is in the zoo before the second training ends, and the export stage has nothing left
    assert runner.ran == ["train/abm_oracle", "export/abm_oracle", "train/abm_oracle_seed1",
                          "export/abm_oracle_seed1"]
    assert (tmp_path / "models/abm_oracle.pt").is_file() and (tmp_path / "models/abm_oracle_seed1.pt").is_file()
    runner.ran.clear()
    Engine(spec, root=tmp_path, runner=runner).run(["train"])  # without the export stage: none
    assert runner.ran == []
    for path in (tmp_path / "models").glob("*.pt"):
        path.unlink()
    (tmp_path / "runs/tiny/abm_oracle_seed1/checkpoints/step_00000003.pt").unlink()
    Engine(spec, root=tmp_path, runner=runner).run(["train"])
    assert runner.ran == ["train/abm_oracle_seed1"] and not list((tmp_path / "models").glob("*.pt"))


def test_a_zoo_file_that_is_not_the_indexed_model_stops_the_engine(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A zoo file counts as an exported training only when it is the model its index entry records: an 8-byte
    file committed in place of the weights would otherwise mark the training done, and nothing would train it."""
    spec, _ = _spec(tmp_path, _two_oracle_runs())
    runner = FakeRunner(tmp_path)
    monkeypatch.setattr(LocalRunner, "run", _fake_export(tmp_path, runner.ran))
    assert Engine(spec, root=tmp_path, runner=runner).run(["train", "export"]) == 0
    assert {j.id: j.state for j in Engine(spec, root=tmp_path).plan("export")}["export/abm_oracle"] == DONE
    (tmp_path / "models/abm_oracle.pt").write_text("abm_oracle")
    with pytest.raises(ZooError, match=r"abm_oracle\.pt is not the model .*index\.json records for abm_oracle \(10 "
                                       r"bytes, the index says 5; or another sha256\): restore it with git checkout"):
        Engine(spec, root=tmp_path).plan("train")
    (tmp_path / "models/abm_oracle.pt").write_text("model")  # the same bytes again: done
    assert {j.id: j.state for j in Engine(spec, root=tmp_path).plan("export")}["export/abm_oracle"] == DONE


def test_a_finished_training_not_exported_yet_is_carried_and_exported_on_a_fresh_clone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    spec, _ = _spec(tmp_path, _two_oracle_runs())
    layout = Layout.of(spec, tmp_path)
    _touch_checkpoint(layout, "abm_oracle", 3)  # finished while its sibling still trained: the session stopped
    _touch_checkpoint(layout, "abm_oracle_seed1", 1)
    assert carry_unfinished(spec, layout) == ["abm_oracle", "abm_oracle_seed1"]
    assert (tmp_path / "models/carry/abm_oracle/step_00000003.pt").is_file()
    fresh = tmp_path / "fresh"
    ran: list[str] = []
    monkeypatch.setattr(LocalRunner, "run", _fake_export(tmp_path, ran))
    restored = {}

    class Resuming(FakeRunner):  # what each training found in its folder when it started
        def run(self, commands, source, slots, on_start=None):
            for cmd in commands:
                original = cmd.before

                def before(cmd=cmd, original=original) -> None:
                    original()
                    found = (tmp_path / cmd.work.config.out / "checkpoints").glob("*.pt")
                    restored[cmd.job] = sorted((p.name, checkpoint_step(p)) for p in found)
                cmd.before = before
            return super().run(commands, source, slots, on_start)

    engine = Engine(spec, root=tmp_path, out=fresh, runner=Resuming(tmp_path))
    assert {j.id: j.note for j in engine.plan("train")}["train/abm_oracle"] == "continues from the carry"
    assert engine.run(["train", "export"]) == 0
    # each training resumed from its carried checkpoint (abm train --resume at the last step trains no more)
    assert restored == {"train/abm_oracle": [("step_00000003.pt", 3)],
                        "train/abm_oracle_seed1": [("step_00000001.pt", 1)]}
    assert ran == ["export/abm_oracle", "export/abm_oracle_seed1"] and (tmp_path / "models/abm_oracle.pt").is_file()
    assert not (tmp_path / "models/carry/abm_oracle").exists()  # exported: its carry is dropped


def test_a_failed_training_stops_before_the_next_stage_and_carries_its_state(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    spec, _ = _spec(tmp_path, _one_run())
    runner = FakeRunner(tmp_path, fail="train/abm_oracle")
    engine = Engine(spec, root=tmp_path, runner=runner)
    _touch_checkpoint(engine.layout, "abm_oracle", 1)
    assert engine.run(["train", "export"]) == 1
    # the terminal says why, from the last line of the job's log that says something (not the progress bar)
    assert ("train/abm_oracle failed (exit code 1): abm: error: --data runs/x/data: no episodes (log: "
            "runs/tiny/logs/train_abm_oracle.log)") in caplog.text
    assert runner.ran == ["train/abm_oracle"]  # export never planned: the stage after a failure does not run
    status = {j.id: j for j in engine.status()}
    failed = status["train/abm_oracle"]
    assert failed.state == "failed" and "logs/train_abm_oracle.log" in failed.note
    assert (tmp_path / "models/carry/abm_oracle/step_00000001.pt").is_file()  # the carry of the unfinished run


def test_a_stopped_stage_closes_its_spans_and_leaves_the_job_to_do(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path, _one_run())
    engine = Engine(spec, root=tmp_path, runner=FakeRunner(tmp_path, stop="train/abm_oracle"))
    _touch_checkpoint(engine.layout, "abm_oracle", 1)
    with pytest.raises(KeyboardInterrupt):
        engine.run(["train", "export"])
    last = [json.loads(line) for line in engine.layout.jobs.read_text().splitlines()][-1]
    assert last["job"] == "train/abm_oracle" and last["event"] == "end" and last["stopped"] and last["rc"] is None
    assert engine.layout.times.read_text().split()[0::3] == ["train_start", "train_end"]  # the stage's minutes count
    kept = engine.layout.kept / "times.txt"  # kept with the carry: a fresh clone counts this session's minutes
    assert kept.read_text() == engine.layout.times.read_text() and (engine.layout.kept / "machines.txt").is_file()
    status = {j.id: j for j in Engine(spec, root=tmp_path).status()}
    assert status["train/abm_oracle"].state == LEFT  # neither failed nor done: the next run resumes it
    assert (tmp_path / "models/carry/abm_oracle/step_00000001.pt").is_file()


def test_an_evaluation_finished_before_a_stop_is_kept_for_a_fresh_clone(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    # finished, it is not carried (the carry holds unfinished work), so the stop must keep it as the report would
    data = _one_run()
    data["evaluation"]["splits"] = {"seen": {"tasks": "two"}, "unseen": {"tasks": "two"}}
    spec, _ = _spec(tmp_path, data)
    runner = FakeRunner(tmp_path, stop="eval/abm_oracle/unseen")
    monkeypatch.setattr(LocalRunner, "run", _fake_export(tmp_path, runner.ran))
    assert Engine(spec, root=tmp_path, runner=runner).run(["train", "export"]) == 0
    engine = Engine(spec, root=tmp_path, runner=runner)
    with pytest.raises(KeyboardInterrupt):
        engine.run(["eval", "report"])
    kept = engine.layout.kept / "abm_oracle_seen.json"
    assert kept.read_bytes() == (engine.layout.eval_dir("abm_oracle", "seen") / "results.json").read_bytes()
    assert not (engine.layout.kept / "abm_oracle_unseen.json").exists()  # stopped: left, not kept
    shutil.rmtree(tmp_path / "runs")  # a fresh clone: only what is committed
    fresh = {j.id: j.state for j in Engine(spec, root=tmp_path, runner=FakeRunner(tmp_path)).plan("eval")}
    assert fresh == {"eval/abm_oracle/seen": DONE, "eval/abm_oracle/unseen": LEFT}
    runner = FakeRunner(tmp_path)
    assert Engine(spec, root=tmp_path, runner=runner).run(["eval"]) == 0
    assert runner.ran == ["eval/abm_oracle/unseen"]  # the kept one is restored, not run again


def test_a_job_resumed_over_sessions_counts_every_session_s_minutes() -> None:
    events = [{"event": "start", "time": 0.0}, {"event": "end", "time": 600.0, "rc": None, "stopped": True},
              {"event": "start", "time": 1000.0},  # the machine went down: no end, no minutes
              {"event": "start", "time": 2000.0}, {"event": "end", "time": 2300.0, "rc": 0}]
    assert span_minutes(events) == pytest.approx(15.0)
    assert span_minutes(events[:1]) is None


def test_unfinished_work_is_carried_and_continues_on_a_fresh_clone(tmp_path: Path, monkeypatch,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.chdir(tmp_path)  # the project root the engine runs from
    spec, _ = _spec(tmp_path)
    layout = Layout.of(spec, tmp_path)
    _touch_checkpoint(layout, "abm_oracle", 1)
    _touch_checkpoint(layout, "abm_oracle", 2)
    (layout.run_dir("abm_oracle") / "log.csv").write_text("step,elapsed_s\n2,60\n")
    _touch_checkpoint(layout, "rvt_clip", 3)  # finished and exported: nothing to carry
    (tmp_path / "models").mkdir()
    (tmp_path / "models/rvt_clip.pt").write_bytes(b"model")
    (tmp_path / "models/abm.pt").write_bytes(b"the model evaluated")
    digest = sha256_file(tmp_path / "models/abm.pt")
    ev = layout.eval_dir("abm_oracle", "seen")
    ev.mkdir(parents=True)
    # a log written before checkpoints were recorded relative to the root: the carry names it relative; beside it
    # a row of another file's bytes and one written before rows recorded the sha256: neither is ever counted
    rows = [EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, True, checkpoint=str(tmp_path / "models/abm.pt"),
                           checkpoint_sha256=digest),
            EpisodeOutcome("abm", "pick_block", "seen", 0, 1, 2, True, checkpoint="models/abm.pt",
                           checkpoint_sha256="0" * 64),
            EpisodeOutcome("abm", "pick_block", "seen", 0, 2, 3, True, checkpoint="models/abm.pt")]
    (ev / "outcomes.jsonl").write_text("".join(json.dumps(asdict(r)) + "\n" for r in rows))
    done = layout.eval_dir("rvt_clip", "seen")
    done.mkdir(parents=True)
    (done / "outcomes.jsonl").write_text("{}\n")
    (done / "results.json").write_text("[]")
    assert carry_unfinished(spec, layout) == ["eval/abm_oracle/seen", "abm_oracle"]
    assert sorted(p.name for p in (tmp_path / "models/carry/abm_oracle").iterdir()) == [
        "carried.json", "log.csv", "step_00000002.pt"]  # with the manifest of what the carry wrote
    fresh = Layout.of(spec, tmp_path, tmp_path / "fresh")
    assert restore_training(fresh, "abm_oracle")
    assert restore_evaluation(fresh, "abm_oracle", "seen", tmp_path / "models/abm.pt")
    assert "2 of 3 carried outcome(s) refused: not of models/abm.pt's bytes" in caplog.text
    assert (fresh.run_dir("abm_oracle") / "checkpoints/step_00000002.pt").is_file()
    carried = (fresh.eval_dir("abm_oracle", "seen") / "outcomes.jsonl").read_text()
    assert str(tmp_path) not in carried and json.loads(carried)["checkpoint"] == "models/abm.pt"
    assert len(carried.splitlines()) == 1 and json.loads(carried)["checkpoint_sha256"] == digest
    assert not restore_training(fresh, "abm_oracle")  # it has its own checkpoints now: never overwritten
    assert not restore_evaluation(fresh, "rvt_clip", "seen")


def _sleeper(tmp_path: Path, name: str) -> Command:
    code = ("import os, sys, time; open(sys.argv[1], 'w').write(os.environ['OMP_NUM_THREADS'] + ' ' "
            "+ str(time.time())); time.sleep(0.6); open(sys.argv[1], 'a').write(' ' + str(time.time()))")
    return Command(name, [sys.executable, "-c", code, str(tmp_path / f"{name}.txt")], tmp_path / f"{name}.log",
                   tmp_path, threads=1)


def test_the_local_runner_runs_n_at_a_time_and_gives_a_lone_job_every_thread(tmp_path: Path) -> None:
    ended, before = [], {}
    commands = [_sleeper(tmp_path, n) for n in ("a", "b", "c")]
    for cmd in commands:
        cmd.after = lambda code, job=cmd.job: ended.append((job, code))
        cmd.before = lambda job=cmd.job: before.setdefault(job, time.time())
    codes = LocalRunner().run(commands, Source(None), slots=2)
    assert codes == {"a": 0, "b": 0, "c": 0} and sorted(ended) == [("a", 0), ("b", 0), ("c", 0)]
    spans = {n: (tmp_path / f"{n}.txt").read_text().split() for n in "abc"}
    threads = {n: s[0] for n, s in spans.items()}
    assert threads == {"a": "1", "b": "1", "c": "2"}  # c ran alone: both slots' threads
    a_end, b_end, c_start = float(spans["a"][2]), float(spans["b"][2]), float(spans["c"][1])
    assert c_start >= min(a_end, b_end) - 0.05  # never three at a time
    # each job's before() ran right before it started, not when the stage began (c waited for a slot)
    assert before["c"] >= min(a_end, b_end) - 0.05 and before["c"] <= c_start


def test_threads_given_on_the_command_line_hold_for_every_training_also_a_lone_one(tmp_path: Path) -> None:
    (cmd,) = [_sleeper(tmp_path, "lone")]
    assert LocalRunner(lend_idle_threads=False).run([cmd], Source(None), slots=2) == {"lone": 0}
    assert (tmp_path / "lone.txt").read_text().split()[0] == "1"  # another run shares the machine: no more
    spec, _ = _spec(tmp_path, _one_run())
    engine = Engine(spec, root=tmp_path, threads=3)
    (train,) = engine.plan("train")
    assert train.threads == 3 and engine.slots("train") == (2, 3)
    assert not engine._runner(3).lend_idle_threads and Engine(spec, root=tmp_path)._runner(1).lend_idle_threads
    assert Engine(spec, root=tmp_path).plan("train")[0].threads == 1  # the spec's resources.threads_each
    with pytest.raises(ConfigError, match="--threads 0: a training needs at least one thread"):
        Engine(spec, root=tmp_path, threads=0)


def test_the_local_runner_stops_its_jobs_when_interrupted(tmp_path: Path) -> None:
    cmd = Command("long", [sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "long.log", tmp_path)
    started = []

    def interrupt() -> None:
        while not started:
            time.sleep(0.05)
        import _thread

        _thread.interrupt_main()

    import signal

    # interrupt_main() does nothing where SIGINT is ignored (a job started in the background by a shell): make sure
    # Python's own handler is in place for the test, as it is in an interactive session
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Thread(target=interrupt, daemon=True).start()
        began = time.time()
        with pytest.raises(KeyboardInterrupt):
            LocalRunner().run([cmd], Source(None), 1, on_start=lambda c, pid: started.append(pid))
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.time() - began < 30
    import os

    with pytest.raises(ProcessLookupError):
        os.kill(started[0], 0)


def test_the_ray_runner_sends_every_command_through_the_ray_pool(tmp_path: Path, monkeypatch) -> None:
    from concurrent.futures import ThreadPoolExecutor

    import abm.ray_pool

    made = {}

    class FakePool:
        def __init__(self, workers, address=None, initializer=None, cpus_per_worker=1):
            made.update(workers=workers, address=address, initializer=initializer, cpus=cpus_per_worker)
            self.pool = ThreadPoolExecutor(workers)

        def submit(self, fn, *args):
            return self.pool.submit(fn, *args)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.pool.shutdown()

    monkeypatch.setattr(abm.ray_pool, "RayActorPool", FakePool)
    commands = [_sleeper(tmp_path, n) for n in ("a", "b")]
    assert RayRunner("10.0.0.1:6379", cpus=2).run(commands, Source(None), slots=2) == {"a": 0, "b": 0}
    assert made == {"workers": 2, "address": "10.0.0.1:6379", "initializer": None, "cpus": 2}
    assert (tmp_path / "a.txt").read_text().split()[0] == "1"


def test_a_source_tree_goes_first_on_the_jobs_path(tmp_path: Path) -> None:
    tree = tmp_path / "tree"
    (tree / "src/abm").mkdir(parents=True)
    (tree / "src/abm/__init__.py").write_text("")
    source = Source.at(tree)
    assert source.env(3)["PYTHONPATH"].split(":")[0] == str(tree.resolve() / "src")
    assert source.env(3)["OMP_NUM_THREADS"] == "3"
    assert source.job("runs/x/jobs/train_a.json") == [sys.executable, "-m", "abm.experiments.jobs",
                                                      "runs/x/jobs/train_a.json"]
    with pytest.raises(ValueError, match="not an abm checkout"):
        Source.at(tmp_path / "nowhere")
    assert scheduler.Source.here().tree is not None  # the tests run from a checkout


def test_the_command_line_runs_status_and_lists(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _, path = _spec(tmp_path)
    assert main(["experiment", "status", str(path), "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "train/rvt_clip" in out and "blocked" in out and "no benchmark CLIP" in out
    assert main(["experiment", "run", str(path), "--root", str(tmp_path), "--stages", "data", "--dry-run"]) == 0
    assert not (tmp_path / "runs").exists()  # a dry run writes nothing
    assert main(["experiment", "list"]) == 0
    assert "paper_tables" in capsys.readouterr().out
    (tmp_path / "bad.yaml").write_text("name: bad\n")
    assert main(["experiment", "status", str(tmp_path / "bad.yaml")]) == 2
    assert "bad.yaml: data.tasks: is required (a list of names)" in capsys.readouterr().err


def test_status_sees_a_training_that_holds_its_run_folder(tmp_path: Path) -> None:
    from abm.files import FolderLock

    spec, _ = _spec(tmp_path, _one_run())
    engine = Engine(spec, root=tmp_path)
    assert {j.id: j.state for j in engine.status()}["train/abm_oracle"] == LEFT
    with FolderLock(engine.layout.run_dir("abm_oracle"), "abm train"):  # as `abm train` holds it while it runs
        (engine.layout.run_dir("abm_oracle") / "log.csv").write_text("step,elapsed_s\n250,600\n")
        job = {j.id: j for j in engine.status()}["train/abm_oracle"]
        assert (job.state, job.note) == ("running", "step 250/3")
    assert {j.id: j.state for j in engine.status()}["train/abm_oracle"] == LEFT
