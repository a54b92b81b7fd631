"""The README gate (``report.readme_when``, abm.experiments.report.gate) and the headline's differences held to a
seed spread (issue 54 items 2 and 5): the third edition declares its README blocks and zoo README now, and the
report writes them only once Tables 1 and 2 (with Table 1's seed pairs) are complete; until then the README and
the zoo's README stay the second edition's, and ``abm experiment status`` says what the gate waits for."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from tests.test_experiment_report_v2 import _rate

from abm.cli import main
from abm.experiments import report as rep
from abm.experiments.report.sections.headline import against_spread
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import Layout
from abm.zoo import pick

REPO = Path(__file__).resolve().parents[1]
V3 = load_spec("paper_tables_v3")
PAPER, COMPOSITIONAL = V3.split_tasks()["seen"], V3.split_tasks()["compositional"]
TABLE_1 = ("rvt_clip", "ifd_clip", "abm_clip", "abm_clip_hash", "abm_oracle")
#: (run, split) -> the success (%) of every task: abm 2 points above rvt on seen objects (within the seed spread of
#: 3), 35 on unseen ones (more than the spread of 5)
SUCCESS = {**{(run, split): 40.0 for run in TABLE_1 for split in ("seen", "unseen", "compositional")},
           ("abm_clip", "seen"): 52.0, ("abm_clip", "unseen"): 55.0, ("abm_clip", "compositional"): 50.0,
           ("rvt_clip", "seen"): 50.0, ("rvt_clip", "unseen"): 20.0, ("rvt_clip", "compositional"): 10.0}
SEED_PAIRS = {("abm_clip_seed1", "seen"): 54.0, ("abm_clip_seed1", "unseen"): 50.0,
              ("rvt_clip_seed1", "seen"): 47.0, ("rvt_clip_seed1", "unseen"): 22.0}
GATED = ("README.md", "models/README.md")


def _root(tmp_path: Path) -> Path:
    """A scratch root with the repository's README, the zoo's index and README (the second edition's), the model
    files and the benchmark CLIP linked, nothing run."""
    root = tmp_path / "root"
    (root / "models").mkdir(parents=True)
    for name in (*GATED, "models/index.json"):
        shutil.copyfile(REPO / name, root / name)
    for model in (REPO / "models").iterdir():
        if model.suffix == ".pt" or model.name == "benchmark-clip":
            (root / "models" / model.name).symlink_to(model)
    return root


def _evaluate(layout: Layout, success: dict[tuple[str, str], float], kept: bool = False) -> None:
    """Evaluation JSON of every (run, split) of ``success`` (each task at that success, three repeats) under OUT,
    or only in KEPT as on a fresh clone (``kept``)."""
    for (run, split), value in success.items():
        tasks = COMPOSITIONAL if split == "compositional" else PAPER
        path = layout.kept / f"{run}_{split}.json" if kept else layout.eval_dir(run, split) / "results.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps([_rate(t, split, [value] * 3) for t in tasks]))


def _export_v3(root: Path) -> None:
    """The third edition's abm_clip and rvt_clip as exported (stand-in files) and indexed by their export."""
    for run in ("abm_clip", "rvt_clip"):
        stand_in = root / "models" / f"{run}_v3.pt"
        stand_in.unlink(missing_ok=True)  # a link to the checkout's model (_root): never written through
        stand_in.write_bytes(run.encode())
    Engine(V3, root=root).write_zoo_index()


def _zoo_eval_models(root: Path) -> dict[str, str]:
    """The models ``abm zoo eval`` would run (:func:`abm.zoo.pick` on the root's index)."""
    entries = json.loads((root / "models/index.json").read_text())  # (read_index refuses the linked files)
    return {method: pick(entries, method)["name"] for method in ("abm", "rvt")}


def _status(root: Path, capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert main(["experiment", "status", "paper_tables_v3", "--root", str(root)]) == 0
    return next(line for line in capsys.readouterr().out.splitlines() if line.startswith("README gate"))


def test_a_closed_gate_leaves_the_readme_and_the_zoo_readme_as_they_are(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    root = _root(tmp_path)
    before = {name: (root / name).read_bytes() for name in GATED}
    _export_v3(root)
    _evaluate(Layout.of(V3, root), SUCCESS)  # Tables 1 and 2 complete, but not Table 1's seed pairs
    with caplog.at_level("INFO"):
        assert Engine(V3, root=root).run(["report"]) == 0
    assert {name: (root / name).read_bytes() for name in GATED} == before  # the second edition's, byte for byte
    # the exported third-edition models are in the index, but abm zoo eval keeps the second edition's until the gate
    assert _zoo_eval_models(root) == {"abm": "abm_clip_v2", "rvt": "rvt_clip_v2"}
    index = json.loads((root / "models/index.json").read_text())
    third = {e["name"]: e["compared"] for e in index if e.get("edition") == 3}  # and those exported since
    assert {"abm_clip_v3", "rvt_clip_v3"} <= set(third) and not any(third.values())
    assert "**Table 1**" in (root / V3.report.document).read_text()  # the edition's own page is written
    waiting = "Tables 1 and 2 are complete (Table 1: 80 of 112 cells evaluated, its seed pairs' included)"
    assert f"report: left README.md's paper-tables and headline blocks and models/README.md unchanged until " \
           f"{waiting}" in caplog.text
    assert "the paper-tables and headline blocks of README.md" not in caplog.text
    assert _status(root, capsys) == ("README gate (report.readme_when): closed: the report leaves README.md's "
                                     f"paper-tables and headline blocks and models/README.md unchanged until {waiting}")


def test_the_status_counts_the_kept_cells_of_a_fresh_clone(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path)
    assert _status(root, capsys).endswith("(Table 1: 0 of 112 cells evaluated, its seed pairs' included; Table 2: "
                                          "0 of 10)")
    compositional = {key: value for key, value in SUCCESS.items() if key[1] == "compositional"}
    _evaluate(Layout.of(V3, root), compositional, kept=True)  # committed, not restored into OUT yet
    assert _status(root, capsys).endswith("until Tables 1 and 2 are complete (Table 1: 0 of 112 cells evaluated, "
                                          "its seed pairs' included)")  # Table 2 complete: no longer named


def test_the_gate_opens_once_table_1s_seed_pairs_are_in_and_the_headline_holds_differences_to_the_spread(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = _root(tmp_path)
    _export_v3(root)
    _evaluate(Layout.of(V3, root), {**SUCCESS, **SEED_PAIRS})
    assert Engine(V3, root=root).run(["report"]) == 0
    assert _zoo_eval_models(root) == {"abm": "abm_clip_v3", "rvt": "rvt_clip_v3"}  # switched with the README
    readme = (root / "README.md").read_text()
    headline = rep.block_of(readme, "headline")
    # Table 1's seed spread: seen 3 (rvt 50 / 47), unseen 5 (abm 55 / 50)
    assert ("abm succeeds in 55.0 % of the episodes and the rvt baseline in 20.0 % (the paper: 57.5 % and 24.0 %), a "
            "difference of 35.0 points, more than the seed spread of 5.0 points") in headline
    assert "52.0 % against 50.0 % (2.0 points, within the seed spread of 3.0 points)" in headline
    assert "| abm (CLIP mask fields), ours | 52.0 | 55.0 | 50.0 |" in headline
    block = rep.block_of(readme, "paper-tables")
    assert block.startswith("Written by `abm experiment run paper_tables_v3`") and "**Table 1**" in block
    assert "(docs/results/paper_tables_v3.md#diagnosis)" in block and "## Diagnosis" not in block  # on the page
    assert rep.block_of(readme, "seen-unseen") == rep.block_of((REPO / "README.md").read_text(), "seen-unseen")
    zoo = (root / "models/README.md").read_text()
    assert zoo.startswith("# Model zoo\n\nWritten by `abm experiment run paper_tables_v3`")
    assert "three editions" in zoo and "`NAME_v3.pt`" in zoo
    assert _status(root, capsys) == ("README gate (report.readme_when): open (Tables 1 and 2 complete): the report "
                                     "writes README.md's paper-tables and headline blocks and models/README.md")


def test_a_difference_against_the_spread() -> None:
    assert against_spread(-6.0, 5.0, 1) == "more than the seed spread of 5.0 points"  # either way round
    assert against_spread(5.0, 5.0, 1) == "within the seed spread of 5.0 points"  # not larger: within
    assert against_spread(None, 5.0, 1) == against_spread(3.0, None, 1) == "–"  # the text waits for both


def _spec_with(tmp_path: Path, change) -> Path:
    data = yaml.safe_load(V3.path.read_text())
    change(data["report"])
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    return path


def _headline(report: dict) -> dict:
    return report["blocks"]["headline"][0]


@pytest.mark.parametrize(("change", "message"), [
    (lambda r: r.update(readme_when={"complete": [4]}), r"readme_when.complete: 4: no table of this report \(its "
                                                        r"tables: 1, 2, 3\)"),
    (lambda r: r.update(readme_when={"complete": []}), "readme_when.complete: expected a list of the report's table"),
    (lambda r: r.update(readme_when={"complete": [1], "seeds": True}), r"readme_when: unknown keys \['seeds'\]"),
    (lambda r: [r.pop(k) for k in ("readme", "block", "blocks", "zoo_readme")],
     "report.readme_when: holds back nothing"),
    (lambda r: _headline(r).update(text="{abm_clip_unseen_minus_ifd_clip}"),
     r"text: \{abm_clip_unseen_minus_ifd_clip\}: no such value"),
    (lambda r: _headline(r).pop("of_table"), r"\{abm_clip_seen_minus_rvt_clip_vs_spread\}, "
                                             r"\{abm_clip_unseen_minus_rvt_clip_vs_spread\}: no such value"),
    (lambda r: _headline(r).update(of_table=2), "the headline: table 2 has no seeds section"),
    (lambda r: _headline(r).update(text="{abm_clip_seen"), "a template with unbalanced braces"),
])
def test_the_gate_and_the_headline_are_checked_when_the_spec_loads(tmp_path: Path, change, message: str) -> None:
    with pytest.raises(SpecError, match=message):
        load_spec(_spec_with(tmp_path, change))


def test_the_earlier_editions_have_no_gate_and_no_readme_block_any_more() -> None:
    for name in ("paper_tables", "paper_tables_v2"):  # the third edition's gate opened: it alone writes the README
        spec = load_spec(name)
        assert spec.report.readme_when is None and not spec.report.readme and not spec.report.blocks
