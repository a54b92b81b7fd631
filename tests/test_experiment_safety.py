"""An experiment spec cannot write outside its root or over files the engine did not write (issue 57): every
path resolved inside ``--root``, the report replaces only its own files, the carry removes only what its
manifest lists, and every value passes its flag's check before any job runs."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from tests.test_experiments import FakeRunner, _one_run, _touch_checkpoint, _with

from abm.cli import main
from abm.evaluation.results import EpisodeOutcome, OutcomeLog
from abm.experiments.report import NotOwnedError, write_report
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import (
    CarryError,
    Layout,
    carry_unfinished,
    drop_carry,
    log_job,
    merge_lines,
    restore_evaluation,
    restore_training,
    stage_minutes,
)
from abm.files import FolderBusyError, FolderLock, sha256_file
from abm.policy.checkpoint import load_checkpoint, save_checkpoint


def _write_spec(root: Path, data: dict, name: str = "tiny.yaml") -> Path:
    path = root / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_run_s_recipe_is_checked_like_abm_train_before_any_job(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    bad = _with(training__policy={"resolution": 32, "patch_size": 6})
    with pytest.raises(SpecError, match=r"tiny\.yaml: runs\.abm_oracle \(the recipe quickstart with the spec's "
                                        r"overrides\): policy: patch_size 6 must divide the view resolution 32"):
        load_spec(_write_spec(tmp_path, bad))  # when the spec loads
    steps = _with(runs__abm_oracle__train={"method": "abm", "lr": float("inf")})  # refused like --lr inf
    path = _write_spec(tmp_path, steps, "inf.yaml")
    assert main(["experiment", "run", str(path), "--root", str(tmp_path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("abm: error: ") and "lr" in err
    assert not (tmp_path / "runs").exists()  # nothing ran, nothing was written


def test_a_folder_of_the_spec_that_leads_out_of_the_root_through_a_link_is_refused(tmp_path: Path) -> None:
    root, outside = tmp_path / "root", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    (root / "runs").symlink_to(outside)
    spec = load_spec(_write_spec(root, _one_run()))
    with pytest.raises(SpecError, match=r"out: 'runs/tiny' leads outside the root .* \(through a symbolic link\)"):
        Layout.of(spec, root)
    with pytest.raises(SpecError, match=r"--out .* is the root itself .*: give a working folder inside it"):
        Layout.of(load_spec(_write_spec(root, _with(out="work"))), root, root)


def test_the_report_replaces_only_the_files_it_wrote_and_never_the_spec(tmp_path: Path) -> None:
    spec_path = _write_spec(tmp_path, _with(report__document="tiny.yaml", report__records=""))
    layout = Layout.of(load_spec(spec_path), tmp_path)
    before = spec_path.read_bytes()
    with pytest.raises(NotOwnedError, match=r"the report's document tiny\.yaml is the spec itself"):
        write_report(load_spec(spec_path), layout)
    assert spec_path.read_bytes() == before
    notes = tmp_path / "docs/notes.md"
    notes.parent.mkdir()
    notes.write_text("# My notes\n\nwritten by hand\n")
    spec = load_spec(_write_spec(tmp_path, _with(report__document="docs/notes.md", report__records=""), "b.yaml"))
    with pytest.raises(NotOwnedError, match=r"docs/notes\.md exists and was not written by abm experiment run tiny"):
        write_report(spec, Layout.of(spec, tmp_path))
    assert notes.read_text() == "# My notes\n\nwritten by hand\n"
    notes.unlink()  # a new file is the report's; rewriting its own document is fine
    write_report(spec, Layout.of(spec, tmp_path))
    write_report(spec, Layout.of(spec, tmp_path))
    assert notes.read_text().startswith("# Tiny\n\nWritten by `abm experiment run tiny` ([b.yaml](../b.yaml))")


def test_the_carry_removes_only_what_it_wrote(tmp_path: Path) -> None:
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    layout = Layout.of(spec, tmp_path)
    _touch_checkpoint(layout, "abm_oracle", 1)
    mine = tmp_path / "models/carry/abm_oracle"
    mine.mkdir(parents=True)
    (mine / "thesis.tex").write_text("not the engine's")
    with pytest.raises(CarryError, match=r"holds files the carry did not write \(thesis\.tex\); it removes only what"):
        carry_unfinished(spec, layout)
    assert (mine / "thesis.tex").read_text() == "not the engine's"
    (mine / "thesis.tex").unlink()
    assert carry_unfinished(spec, layout) == ["abm_oracle"]
    manifest = json.loads((mine / "carried.json").read_text())
    assert sorted(manifest["files"]) == ["step_00000001.pt"] and len(manifest["files"]["step_00000001.pt"]) == 64
    (mine / "notes.txt").write_text("added later by hand")
    drop_carry(layout, "abm_oracle")
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]  # its own files gone, the other one stays


def test_carry_on_a_spec_without_a_carry_says_so_in_one_line(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    data = _one_run()
    data.pop("carry")
    path = _write_spec(tmp_path, data)
    assert main(["experiment", "run", str(path), "--root", str(tmp_path), "--stages", "carry"]) == 2
    err = capsys.readouterr().err
    assert err == ("abm: error: --stages carry: tiny keeps no carry (its spec has no carry: folder), so there is "
                   "nothing to carry into; add carry: FOLDER to the spec, or leave carry out\n")


# ------------------------------------------------------------------------------ one engine per working folder
def test_a_second_engine_on_a_working_folder_says_already_running_and_starts_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write_spec(tmp_path, _one_run())
    spec = load_spec(path)
    runner = FakeRunner(tmp_path)
    engine = Engine(spec, root=tmp_path, runner=runner)
    with FolderLock(engine.layout.out, "abm experiment run tiny"):  # the first engine, still running
        with pytest.raises(FolderBusyError, match=rf"abm experiment run tiny: already running \(pid {os.getpid()} on "
                                                  r"\S+\) in runs/tiny; nothing started"):
            engine.run(["train"])
        assert main(["experiment", "run", str(path), "--root", str(tmp_path), "--stages", "train"]) == 2
    assert runner.ran == [] and not engine.layout.jobs.exists()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already running (pid" in err


def test_a_job_left_running_by_a_killed_engine_is_not_started_twice(tmp_path: Path,
                                                                     caplog: pytest.LogCaptureFixture) -> None:
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    runner = FakeRunner(tmp_path)
    engine = Engine(spec, root=tmp_path, runner=runner)
    _touch_checkpoint(engine.layout, "abm_oracle", 1)
    with FolderLock(engine.layout.run_dir("abm_oracle"), "abm train"):  # the orphaned training holds its folder
        assert engine.run(["train", "export"]) == 1
    assert runner.ran == []
    assert f"train/abm_oracle: already running (pid {os.getpid()} on " in caplog.text


def test_stage_minutes_pair_each_session_s_start_and_end_and_two_working_folders_keep_both(tmp_path: Path) -> None:
    times = tmp_path / "times.txt"
    # two engines' train stages interleave: 0-600 s and 60-1200 s, plus an older file's unpaired lines
    times.write_text("eval_start 0\neval_end 120\ntrain_start 0 a:1\ntrain_start 60 b:2\ntrain_end 600 a:1\n"
                     "train_end 1200 b:2\n")
    assert stage_minutes(times) == {"eval": pytest.approx(2.0), "train": pytest.approx(10.0 + 19.0)}
    kept, first, second = tmp_path / "kept.txt", tmp_path / "one.txt", tmp_path / "two.txt"
    first.write_text("train_start 0 a:1\ntrain_end 600 a:1\n")
    second.write_text("train_start 60 b:2\ntrain_end 1200 b:2\n")
    kept.write_bytes(merge_lines(first, kept))
    kept.write_bytes(merge_lines(second, kept))
    kept.write_bytes(merge_lines(first, kept))  # keeping again adds nothing
    assert stage_minutes(kept) == {"train": pytest.approx(29.0)}
    assert len(kept.read_text().splitlines()) == 4


# ---------------------------------------------------------------------------- carried work bound to its bytes
def test_every_outcome_row_records_its_checkpoint_s_sha256(tmp_path: Path) -> None:
    model = tmp_path / "m.pt"
    model.write_bytes(b"weights")
    log = OutcomeLog(tmp_path / "outcomes.jsonl")
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, True, checkpoint=str(model)))
    assert log.read()[0].checkpoint_sha256 == sha256_file(model)


def test_a_training_is_finished_by_the_step_its_checkpoint_holds_not_its_name(tmp_path: Path) -> None:
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    engine = Engine(spec, root=tmp_path)
    folder = engine.layout.run_dir("abm_oracle") / "checkpoints"
    folder.mkdir(parents=True)
    save_checkpoint(folder / "step_00000003.pt", {"step": 1})  # named as the last step, holding the first
    assert not engine.trained("abm_oracle")
    save_checkpoint(folder / "step_00000003.pt", {"step": 3})
    assert engine.trained("abm_oracle")


def _carried(tmp_path: Path) -> tuple[Layout, Layout, Path]:
    """A carried training of abm_oracle at step 1, and a fresh working folder to restore it into."""
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    layout = Layout.of(spec, tmp_path)
    _touch_checkpoint(layout, "abm_oracle", 1)
    assert carry_unfinished(spec, layout) == ["abm_oracle"]
    return layout, Layout.of(spec, tmp_path, tmp_path / "fresh"), tmp_path / "models/carry/abm_oracle"


def test_a_finished_training_is_carried_without_its_training_state(tmp_path: Path) -> None:
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    layout = Layout.of(spec, tmp_path)
    steps = spec.runs["abm_oracle"].config.steps
    folder = layout.run_dir("abm_oracle") / "checkpoints"
    folder.mkdir(parents=True)
    weights = {"w": torch.arange(6.0)}
    state = {"step": steps - 1, "model": weights, "optimizer": {"state": {0: {"exp_avg": torch.ones(100_000)}}},
             "scheduler": {"last_epoch": steps - 1}, "rng": {"seed": 0}}
    save_checkpoint(folder / f"step_{steps - 1:08d}.pt", state)
    assert carry_unfinished(spec, layout) == ["abm_oracle"]  # unfinished: everything, to continue from
    carried = tmp_path / "models/carry/abm_oracle"
    assert "optimizer" in load_checkpoint(carried / f"step_{steps - 1:08d}.pt")
    save_checkpoint(folder / f"step_{steps:08d}.pt", state | {"step": steps})
    assert carry_unfinished(spec, layout) == ["abm_oracle"]  # finished: the weights and records only
    (ckpt,) = (p for p in carried.iterdir() if p.suffix == ".pt")
    slim = load_checkpoint(ckpt)
    assert ckpt.name == f"step_{steps:08d}.pt" and slim["step"] == steps and torch.equal(slim["model"]["w"],
                                                                                          weights["w"])
    assert not {"optimizer", "scheduler", "rng"} & set(slim) and ckpt.stat().st_size < 100_000
    full = folder / f"step_{steps:08d}.pt"
    assert slim["slimmed_from_sha256"] == sha256_file(full)


def test_the_outcomes_of_a_finished_training_are_restored_with_its_slimmed_checkpoint(tmp_path: Path,
                                                                                        monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    layout = Layout.of(spec, tmp_path)
    steps = spec.runs["abm_oracle"].config.steps
    full = layout.run_dir("abm_oracle") / "checkpoints" / f"step_{steps:08d}.pt"
    full.parent.mkdir(parents=True)
    save_checkpoint(full, {"step": steps, "model": {"w": torch.ones(3)}, "optimizer": {"m": torch.ones(50_000)}})
    log = OutcomeLog(layout.eval_dir("abm_oracle", "seen") / "outcomes.jsonl")
    shown = layout.show(full)
    for episode in (0, 1):  # evaluated with the full file before the session ended
        log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, episode, 1 + episode, True, checkpoint=shown))
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 2, 3, True, checkpoint=shown,
                              checkpoint_sha256="another file's"))
    assert sorted(carry_unfinished(spec, layout)) == ["abm_oracle", "eval/abm_oracle/seen"]
    digest = sha256_file(full)
    shutil.rmtree(layout.out)  # the next session, on a fresh machine: only the carry is left
    assert restore_training(layout, "abm_oracle")  # the engine sees the run trained
    assert Engine(spec, root=tmp_path).trained("abm_oracle")
    assert full.is_file() and sha256_file(full) != digest  # slimmed: other bytes, the same weights
    assert restore_evaluation(layout, "abm_oracle", "seen", layout.run_dir("abm_oracle"))
    rows = OutcomeLog(layout.eval_dir("abm_oracle", "seen") / "outcomes.jsonl").read()
    assert [o.episode for o in rows] == [0, 1]  # the full file's rows kept, the other file's refused


def test_a_changed_renamed_or_unsealed_carried_checkpoint_is_refused(tmp_path: Path) -> None:
    _, fresh, carried = _carried(tmp_path)
    ckpt = carried / "step_00000001.pt"
    good = ckpt.read_bytes()
    ckpt.write_bytes(good[:-1] + bytes([good[-1] ^ 1]))  # one flipped bit
    with pytest.raises(CarryError, match=r"step_00000001\.pt does not match the sha256 that .*carried\.json records"):
        restore_training(fresh, "abm_oracle")
    ckpt.unlink()  # a checkpoint of step 1 renamed as the last step, its manifest rewritten to match
    save_checkpoint(carried / "step_00000040.pt", {"step": 1})
    manifest = json.loads((carried / "carried.json").read_text())
    manifest["files"] = {"step_00000040.pt": sha256_file(carried / "step_00000040.pt")}
    (carried / "carried.json").write_text(json.dumps(manifest))
    with pytest.raises(CarryError, match=r"step_00000040\.pt holds step 1 \(its name says 40\): a renamed or foreign"):
        restore_training(fresh, "abm_oracle")
    (carried / "carried.json").unlink()  # a carry folder without a manifest: nothing can be checked
    with pytest.raises(CarryError, match=r"has no manifest \(carried\.json\) of what the carry wrote"):
        restore_training(fresh, "abm_oracle")
    assert not (fresh.run_dir("abm_oracle") / "checkpoints").exists()  # nothing copied


def test_carried_outcomes_of_another_model_never_reach_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.chdir(tmp_path)
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    layout = Layout.of(spec, tmp_path)
    (tmp_path / "models").mkdir()
    weak, other = tmp_path / "models/abm_oracle.pt", tmp_path / "models/strong.pt"
    weak.write_bytes(b"a model that fails")
    other.write_bytes(b"a model that succeeds")
    log = OutcomeLog(layout.eval_dir("abm_oracle", "seen") / "outcomes.jsonl")
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, False, checkpoint="models/abm_oracle.pt"))
    for episode in (1, 2):  # success rows claimed for the right path with another file's sha256
        log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, episode, 1 + episode, True,
                                  checkpoint="models/abm_oracle.pt", checkpoint_sha256=sha256_file(other)))
    assert carry_unfinished(spec, layout) == ["eval/abm_oracle/seen"]
    fresh = Layout.of(spec, tmp_path, tmp_path / "fresh")
    assert restore_evaluation(fresh, "abm_oracle", "seen", weak)
    restored = OutcomeLog(fresh.eval_dir("abm_oracle", "seen") / "outcomes.jsonl").read()
    assert [(o.episode, o.success) for o in restored] == [(0, False)]  # 0/1 so far, never 2/3
    assert "2 of 3 carried outcome(s) refused: not of models/abm_oracle.pt's bytes" in caplog.text


def test_the_report_names_the_spec_relative_to_the_root_never_by_this_machine_s_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "specs").mkdir()
    path = _write_spec(tmp_path / "specs", _with(report__records=""))
    spec = load_spec(path.resolve())  # named by its absolute path, the root given as "."
    write_report(spec, Layout.of(spec, Path(".")))
    text = (tmp_path / "docs/results/tiny.md").read_text()
    assert "Written by `abm experiment run tiny` ([specs/tiny.yaml](../../specs/tiny.yaml))" in text
    assert str(tmp_path) not in text
    elsewhere = tmp_path / "root"
    elsewhere.mkdir()  # a spec outside the root: named by its file name alone
    write_report(spec, Layout.of(spec, elsewhere))
    assert str(tmp_path) not in (elsewhere / "docs/results/tiny.md").read_text()


def test_a_job_s_live_pid_in_the_job_log_counts_only_if_that_process_runs_the_job(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    spec = load_spec(_write_spec(tmp_path, _one_run()))
    sleep = [sys.executable, "-c", "import time; time.sleep(60)"]
    for argv, started in (([*sleep, "runs/tiny/jobs/train_abm_oracle.json"], False), (sleep, True)):
        runner = FakeRunner(tmp_path)
        engine = Engine(spec, root=tmp_path, runner=runner)
        with subprocess.Popen(argv) as orphan:  # the training a killed engine left, or an unrelated process
            try:
                # until the child has exec'd, /proc/PID/cmdline is still this test's own (a loaded machine is slow)
                cmdline = Path(f"/proc/{orphan.pid}/cmdline")
                deadline = time.monotonic() + 30
                while b"time.sleep" not in cmdline.read_bytes() and time.monotonic() < deadline:
                    time.sleep(0.02)
                engine.layout.jobs.unlink(missing_ok=True)
                log_job(engine.layout, "train/abm_oracle", "start", pid=orphan.pid)
                assert engine.run(["train"]) == (0 if started else 1)
            finally:
                orphan.kill()
        assert runner.ran == (["train/abm_oracle"] if started else [])
    assert "train/abm_oracle: already running (pid " in caplog.text
