"""Every probe is a spec whose page the report writes: the zoom probe, finished before the engine, regenerates its
tables from its kept records on a fresh clone (nothing of it is trained again, it carries nothing), and the
other probes' pages hold the report's mark."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from abm.cli import main
from abm.experiments.report import block_of
from abm.experiments.report.files import OWNED
from abm.experiments.spec import SpecError, load_spec, spec_path
from abm.experiments.stages import DONE, Engine

ROOT = Path(__file__).resolve().parents[1]
PAGE = "docs/results/zoom_probe.md"
BLOCKS = ("zoom-probe-fit", "zoom-probe-accuracy", "zoom-probe-rollouts")


def _fresh_clone(tmp_path: Path) -> Path:
    """The zoom probe's committed page and kept records, alone under a new root (no working folder)."""
    for name in (PAGE, "docs/results/zoom_probe.json", "docs/results/zoom_probe"):
        target = tmp_path / name
        target.parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copyfile)(ROOT / name, target)
    return tmp_path


def test_the_zoom_probe_s_report_rewrites_its_tables_byte_for_byte_from_the_kept_records(tmp_path: Path) -> None:
    root = _fresh_clone(tmp_path)
    page = root / PAGE
    committed = page.read_text()
    blanked = committed
    for name in BLOCKS:  # the generated blocks emptied: the report must write them back as committed
        blanked = blanked.replace(block_of(committed, name), "")
    page.write_text(blanked)
    assert main(["experiment", "run", "zoom_probe", "--root", str(root), "--stages", "report"]) == 0
    assert page.read_text() == committed
    fit, accuracy, rollouts = (block_of(committed, name) for name in BLOCKS)
    assert fit.startswith("Written by `abm experiment run zoom_probe` (")  # the report's own block
    assert "| 3000 | two-stage+crop | 1.67 | 1.55 | 1.09 | 3.77 | 1.64 |" in fit  # every step and arm
    assert accuracy.startswith("| task | split | keyframe | single-stage (3000) | two-stage (3000) | "
                               "single-stage+crop (3000) | two-stage+crop (3000) |")  # the arms at their last step
    assert rollouts.endswith("| **average %** | seen / unseen | 40 / 28 | 43 / 39 | 42 / 40 | 78 / 77 |\n")
    assert "Reproduce:" not in "".join((fit, accuracy, rollouts))  # nothing to rerun: the provenance names it


def test_a_finished_spec_runs_only_its_report_and_says_what_is_kept(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    root = _fresh_clone(tmp_path)
    spec = load_spec("zoom_probe")
    assert spec.finished and not spec.carry and not spec.evaluation.splits
    engine = Engine(spec, root=root)
    for stage in ("data", "train"):  # nothing is trained again: every job is done, with nothing to run
        assert all(j.state == DONE and j.note == "finished (kept)" and j.before is None for j in engine.plan(stage))
    assert main(["experiment", "run", "zoom_probe", "--root", str(root)]) == 0  # every stage: only the report
    assert not (root / "runs/zoom_probe/data").exists() and not (root / "runs/zoom_probe/single").exists()
    capsys.readouterr()
    assert main(["experiment", "status", "zoom_probe", "--root", str(root)]) == 0
    out = capsys.readouterr().out
    assert "finished: 2026-11-26" in out and "done 6\n" in out
    assert "kept: docs/results/zoom_probe/ (30 files, " in out and "docs/results/zoom_probe.json (242 kB)" in out
    assert "carried: nothing (this experiment keeps no carry)" in out and "estimate" not in out
    assert [r.label for r in spec.runs.values()] == [
        "single-stage", "two-stage", "single-stage+crop", "two-stage+crop"]  # the records' arm names


def test_a_finished_spec_carries_nothing(tmp_path: Path) -> None:
    data = yaml.safe_load(spec_path("zoom_probe").read_text())
    data["carry"] = "models/carry/zoom_probe"
    path = tmp_path / "zoom.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match=r"zoom\.yaml: carry: a finished experiment carries nothing"):
        load_spec(path)


@pytest.mark.parametrize("name", ["rotation_probe", "clip_grounder", "put_in_container", "destination_probe",
                                  "zoom_probe", "skill_text_probe"])
def test_every_probe_s_page_is_written_by_its_spec_s_report(name: str) -> None:
    """A probe's document holds the report's mark (so its report stage replaces it), or its README blocks are
    between their markers; put_in_container's page, measured before the engine, was regenerated with the mark."""
    spec = load_spec(name)
    if spec.report.document and (ROOT / spec.report.document).is_file():
        assert OWNED["document"]((ROOT / spec.report.document).read_text(), name)
    if spec.report.readme:
        text = (ROOT / spec.report.readme).read_text()
        assert all(f"<!-- {block}:start -->" in text for block in (spec.report.block, *spec.report.blocks))
    assert spec.report.document or spec.report.readme


def test_the_zoom_probe_s_runs_are_the_arms_its_page_describes() -> None:
    """Each run of the spec builds the network its arm trained: the parameter counts of the page's table."""
    from abm.policy.keyframe_policy import KeyframePolicy

    page = (ROOT / PAGE).read_text()
    for run in load_spec("zoom_probe").runs.values():
        config = run.config
        policy = KeyframePolicy(config.policy, config.language_config, config.grounder)
        count = sum(p.numel() for p in policy.parameters())
        (row,) = [line for line in page.splitlines() if line.startswith(f"| {run.label} | ")]  # the arms' table
        assert row.endswith(f"| {count:,} | {config.steps} |")


def test_the_skill_text_probe_s_tables_are_written_from_their_kept_json(tmp_path: Path) -> None:
    page = "docs/results/skill_text_probe.md"
    for name in (page, "docs/results/skill_text_probe"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copyfile)(ROOT / name, tmp_path / name)
    spec = load_spec("skill_text_probe")
    committed = (ROOT / page).read_text()
    blocks = (spec.report.block, *spec.report.blocks)
    assert len(blocks) == len(list((ROOT / "docs/results/skill_text_probe").glob("*_move.json"))) == 11
    blanked = committed
    for name in blocks:
        blanked = blanked.replace(block_of(committed, name), "")
    (tmp_path / page).write_text(blanked)
    assert main(["experiment", "run", "skill_text_probe", "--root", str(tmp_path), "--stages", "report"]) == 0
    assert (tmp_path / page).read_text() == committed
    assert "| **put X in the wine rack** (own) | place_wine | 26.3 | 0.0 |" in block_of(committed, blocks[0])
