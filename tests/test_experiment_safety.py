"""An experiment spec cannot write outside its root or over files the engine did not write (issue 57): every
path resolved inside ``--root``, the report replaces only its own files, the carry removes only what its
manifest lists, and every value passes its flag's check before any job runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from tests.test_experiments import _one_run, _touch_checkpoint, _with

from abm.cli import main
from abm.experiments.report import NotOwnedError, write_report
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import CarryError, Layout, carry_unfinished, drop_carry


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
