"""An experiment spec cannot write outside its root or over files the engine did not write (issue 57): every
path resolved inside ``--root``, the report replaces only its own files, the carry removes only what its
manifest lists, and every value passes its flag's check before any job runs."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml
from tests.test_experiments import FakeRunner, _one_run, _touch_checkpoint, _with

from abm.cli import main
from abm.experiments.report import NotOwnedError, write_report
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import CarryError, Layout, carry_unfinished, drop_carry, merge_lines, stage_minutes
from abm.files import FolderBusyError, FolderLock


def _write_spec(root: Path, data: dict, name: str = "tiny.yaml") -> Path:
    path = root / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_a_run_s_recipe_is_checked_like_abm_train_before_any_job(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    bad = _with(training__policy={"resolution": 32, "patch_size": 6})
    spec = load_spec(_write_spec(tmp_path, bad))
    with pytest.raises(SpecError, match=r"tiny\.yaml: runs\.abm_oracle \(the recipe quickstart with the spec's "
                                        r"overrides\): policy: patch_size 6 must divide the view resolution 32"):
        Engine(spec, root=tmp_path)
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
