"""The ``editions`` report section (issue 54 item 5): each run's averages beside the earlier editions' records, with
this edition's change from the last one, read against Table 1's seed spread."""

from __future__ import annotations

import json
import statistics
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from abm.errors import ConfigError
from abm.experiments import report as rep
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.state import Layout

V3 = load_spec("paper_tables_v3")
TASKS = V3.split_tasks()["seen"]
EDITIONS = next(s for s in V3.report.summary if s.kind == "editions")


def _cells(run: str, split: str, values: list[float]) -> rep.Cells:
    """One cell per seen task, task i at ``values[i % len(values)]`` (so the average is known)."""
    cells: rep.Cells = {}
    for i, task in enumerate(TASKS):
        v = values[i % len(values)]
        cells[(run, task, split)] = {"run": run, "method": "abm", "task": task, "split": split, "per_repeat": [v] * 3,
                                     "episodes": 75, "errors": 0, "mean": v, "std": statistics.pstdev([v] * 3)}
    return cells


def _records(path: Path, cells: rep.Cells, table: int = 1) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [{**cell, "table": table} for cell in cells.values()]
    copy = [{**rows[0], "table": 3, "mean": 0.0}] if rows else []  # a second table's copy of a cell: ignored
    path.write_text(json.dumps(rows + copy))


def _section(tmp_path: Path, cells: rep.Cells) -> str:
    ctx = rep.Context(V3, rep.Outcomes(cells=cells), Layout.of(V3, tmp_path, tmp_path / "out"))
    return "\n\n".join(rep.write_section(ctx, EDITIONS))


def test_the_spec_compares_every_table_run_with_both_earlier_editions() -> None:
    assert list(EDITIONS.earlier.values()) == ["docs/results/paper_tables.json", "docs/results/paper_tables_v2.json"]
    assert {"abm_clip", "rvt_clip", "abm_oracle", "concat-rerendered"} <= set(EDITIONS.runs)
    assert EDITIONS.only == "document" and EDITIONS.of_table == 1


def test_a_row_per_run_and_split_with_the_change_from_the_last_edition(tmp_path: Path) -> None:
    first, second = tmp_path / "docs/results/paper_tables.json", tmp_path / "docs/results/paper_tables_v2.json"
    _records(first, _cells("abm_clip", "seen", [20.0, 30.0]))  # average 25
    _records(second, _cells("abm_clip", "seen", [50.0, 70.0]) | _cells("rvt_clip", "seen", [40.0]))
    now = (_cells("abm_clip", "seen", [74.0, 76.0]) | _cells("abm_clip_seed1", "seen", [72.0])
           | _cells("rvt_clip", "seen", [57.0]))
    text = _section(tmp_path, now)
    assert "| abm_clip | seen | 25.0 | 60.0 | 75.0 | +15.0 |" in text
    assert "| rvt_clip | seen | – | 40.0 | 57.0 | +17.0 |" in text
    assert "| ifd_clip |" not in text  # in no edition: no row
    # the mean change over the two runs evaluated in both, against abm_clip's seed pair (75 vs 72)
    assert "Mean change: seen +16.0 points over 2 run(s) (Table 1's seed spread: 3.0)." in text


def test_a_run_not_evaluated_yet_shows_a_dash_and_is_left_out_of_the_mean(tmp_path: Path) -> None:
    _records(tmp_path / "docs/results/paper_tables.json", {})
    _records(tmp_path / "docs/results/paper_tables_v2.json", _cells("abm_clip", "unseen", [50.0]))
    text = _section(tmp_path, {})
    assert "| abm_clip | unseen | – | 50.0 | – | – |" in text
    assert "Mean change: none measured yet." in text


def test_a_missing_records_file_is_named_and_its_column_left_empty(tmp_path: Path) -> None:
    _records(tmp_path / "docs/results/paper_tables.json", _cells("abm_clip", "seen", [30.0]))
    text = _section(tmp_path, _cells("abm_clip", "seen", [70.0]))
    assert "| abm_clip | seen | 30.0 | – | 70.0 | – |" in text
    assert ("Not in this checkout, so shown as –: the records of the second edition "
            "(docs/results/paper_tables_v2.json).") in text


def test_records_that_are_no_cells_are_an_error(tmp_path: Path) -> None:
    _records(tmp_path / "docs/results/paper_tables.json", {})
    (tmp_path / "docs/results/paper_tables_v2.json").write_text(json.dumps({"abm_clip": 59.0}))
    with pytest.raises(ConfigError, match="paper_tables_v2.json: expected a list of cells"):
        _section(tmp_path, {})


@pytest.mark.parametrize(("earlier", "message"), [
    (None, "earlier editions"),
    ({"second edition": "../elsewhere.json"}, "leaves the root"),
])
def test_the_spec_checks_the_earlier_editions(tmp_path: Path, earlier: dict | None, message: str) -> None:
    data = yaml.safe_load(V3.path.read_text())
    section = next(s for s in data["report"]["summary"] if s["kind"] == "editions")
    section.pop("earlier")
    section.update({} if earlier is None else {"earlier": earlier})
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match=message):
        load_spec(tmp_path / "bad.yaml")


def test_the_committed_earlier_records_read(tmp_path: Path) -> None:
    # the real files: the second edition's abm_clip seen average is its README's 59.0
    ctx = rep.Context(V3, rep.Outcomes(cells={}), Layout.of(V3, Path.cwd(), tmp_path / "out"))
    text = "\n\n".join(rep.write_section(ctx, replace(EDITIONS, runs=("abm_clip",), splits=("seen",))))
    assert "| abm_clip | seen |" in text and "| 59.0 | – | – |" in text
