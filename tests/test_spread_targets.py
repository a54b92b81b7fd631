"""The ``exceeds_spread`` target (issue 54 item 4): every difference between two rows of a table that the README
names exceeds that table's seed spread; met, not met with the numbers, or not measured yet."""

from __future__ import annotations

import statistics
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from abm.experiments import report as rep
from abm.experiments.report.sections.targets import checked
from abm.experiments.spec import Section, SpecError, load_spec
from abm.experiments.state import Layout

V3 = load_spec("paper_tables_v3")
TASKS = V3.split_tasks()["seen"]
SPREAD = next(s for s in V3.report.summary if s.kind == "targets" and any(c.kind == "exceeds_spread"
                                                                          for c in s.checks))


def _cells(run: str, split: str, value: float) -> rep.Cells:
    return {(run, t, split): {"method": "abm", "task": t, "split": split, "per_repeat": [value] * 3,
                              "episodes": 75, "errors": 0, "mean": value, "std": statistics.pstdev([value] * 3)}
            for t in TASKS}


def _verdicts(cells: rep.Cells, tmp_path: Path, section: Section = SPREAD) -> str:
    ctx = rep.Context(V3, rep.Outcomes(cells=cells), Layout.of(V3, tmp_path, tmp_path / "out"))
    (text,) = rep.write_section(ctx, section)
    return text


def _table_3(seen: dict[str, float]) -> rep.Cells:
    cells: rep.Cells = {}
    for run, value in seen.items():
        cells |= _cells(run, "seen", value)
    return cells


def test_met_when_every_named_difference_exceeds_table_3s_seed_spread(tmp_path: Path) -> None:
    # Table 3's seed pair 4 points apart on seen objects; the best fusion 5 to 20 above the others
    cells = _table_3({"concat-rerendered": 60.0, "concat-rerendered_seed1": 56.0, "stack": 40.0, "concat-full": 55.0,
                      "abm_clip_hash": 50.0})
    text = _verdicts(cells, tmp_path)
    assert text.startswith("Target, Table 3's differences against its seed spread (issue 54): ")
    assert ("every seen difference the README names > the seed spread: met (seed spread 4.0 points; "
            "concat-rerendered vs stack 20.0, concat-rerendered vs concat-full 5.0, concat-rerendered vs "
            "abm_clip_hash 10.0)") in text
    # unseen: nothing evaluated, so neither the spread nor the rows: not measured, and never "met"
    assert ("every unseen difference the README names > the seed spread: not measured yet (missing on unseen: "
            "Table 3's seed spread, concat-rerendered's average, stack's average, concat-full's average, "
            "abm_clip_hash's average)") in text


def test_not_met_names_the_differences_within_the_spread(tmp_path: Path) -> None:
    cells = _table_3({"concat-rerendered": 60.0, "concat-rerendered_seed1": 54.0, "stack": 40.0, "concat-full": 57.0,
                      "abm_clip_hash": 63.0})
    text = _verdicts(cells, tmp_path)
    assert ("not met (seed spread 6.0 points; concat-rerendered vs stack 20.0, concat-rerendered vs concat-full 3.0 "
            "(within), concat-rerendered vs abm_clip_hash 3.0 (within))") in text
    # Table 1's seed pairs are another table's spread: a wider one there changes nothing here
    cells |= _cells("abm_clip", "seen", 70.0) | _cells("abm_clip_seed1", "seen", 40.0)
    assert "not met (seed spread 6.0 points;" in _verdicts(cells, tmp_path)


def test_a_missing_cell_is_not_measured_yet(tmp_path: Path) -> None:
    cells = _table_3({"concat-rerendered": 60.0, "concat-rerendered_seed1": 58.0, "stack": 40.0, "concat-full": 30.0,
                      "abm_clip_hash": 20.0})
    del cells[("stack", TASKS[0], "seen")]  # one task of one row not evaluated: no average
    assert "seen difference the README names > the seed spread: not measured yet (missing on seen: stack's " \
           "average)" in _verdicts(cells, tmp_path)
    del cells[("concat-rerendered_seed1", TASKS[0], "seen")]  # nor the spread
    assert "not measured yet (missing on seen: Table 3's seed spread, stack's average)" in _verdicts(cells, tmp_path)


def test_a_margin_raises_the_bar_and_misses_are_no_runs_to_diagnose(tmp_path: Path) -> None:
    check = next(c for c in SPREAD.checks if c.split == "seen")
    section = replace(SPREAD, checks=(replace(check, value=6.0),), explain=True)
    cells = _table_3({"concat-rerendered": 60.0, "concat-rerendered_seed1": 56.0, "stack": 40.0, "concat-full": 50.0,
                      "abm_clip_hash": 49.0})
    assert "not met (seed spread 4.0 + 6 points; concat-rerendered vs stack 20.0, concat-rerendered vs " \
           "concat-full 10.0 (within), concat-rerendered vs abm_clip_hash 11.0)" in _verdicts(cells, tmp_path, section)
    ctx = rep.Context(V3, rep.Outcomes(cells=cells), Layout.of(V3, tmp_path, tmp_path / "out"))
    assert checked(ctx, section)[1] == {}  # a table's difference is no run's miss: target_diagnosis says nothing


@pytest.mark.parametrize(("change", "message"), [
    ({"pairs": [["concat-rerendered", "concat-rerendered"]]}, "pairs: expected a list of pairs of two different runs"),
    ({"pairs": [["concat-rerendered", "nobody"]]}, "pairs: expected a list of pairs of two different runs"),
    ({"pairs": [["concat-rerendered", "rvt_clip"]]}, "rvt_clip is no row of table 3"),
    ({"of_table": 2}, "table 2 has no seeds section to measure its seed spread"),
    ({"of_table": None}, "an exceeds_spread check names its pairs"),
    ({"pairs": []}, "an exceeds_spread check names its pairs"),
])
def test_the_check_is_checked_when_the_spec_loads(tmp_path: Path, change: dict, message: str) -> None:
    data = yaml.safe_load(V3.path.read_text())
    section = next(s for s in data["report"]["summary"] if s["kind"] == "targets" and
                   s["checks"][0]["kind"] == "exceeds_spread")
    section["checks"][0].update(change)
    section["checks"][0] = {k: v for k, v in section["checks"][0].items() if v is not None}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match=message):
        load_spec(bad)


def test_other_kinds_take_no_pairs(tmp_path: Path) -> None:
    data = yaml.safe_load(V3.path.read_text())
    section = next(s for s in data["report"]["summary"] if s["kind"] == "targets")
    section["checks"][0]["pairs"] = [["abm_clip", "rvt_clip"]]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match="pairs"):
        load_spec(bad)


def test_a_seeds_section_only_in_a_readme_block_measures_nothing(tmp_path: Path) -> None:
    # the report measures a table's seed spread from the summary and details only (seed_spread), so the spec refuses
    # a held difference whose table's seeds section sits in a README block
    data = yaml.safe_load(V3.path.read_text())
    for part in ("summary", "details"):
        seeds = [s for s in data["report"].get(part, []) if s["kind"] == "seeds" and s["of_table"] == 1]
        data["report"][part] = [s for s in data["report"].get(part, []) if s not in seeds]
        data["report"]["blocks"]["headline"] += seeds
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match="the headline: table 1 has no seeds section to measure its seed spread"):
        load_spec(bad)
