"""The report sections of the paper tables' second edition (abm.experiments.report, spec paper_tables_v2), on
small synthetic outcome records: averages with their standard error over the repeats, the seed spread of Table 3,
the diagnosis per model (keyframe accuracy beside a random yaw's error, the skill-text probe, failure reasons),
targets that say what the diagnosis shows when missed, and a zoo that holds both editions."""

from __future__ import annotations

import hashlib
import json
import math
import statistics
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from abm.experiments import report as rep
from abm.experiments.spec import Section, SpecError, load_spec
from abm.experiments.state import Layout, kept_pairs
from abm.zoo import pick, read_index

V2 = load_spec("paper_tables_v2")
V1 = load_spec("paper_tables")
TASKS = V2.split_tasks()["seen"]


def _rate(task: str, split: str, per_repeat: list[float], failures: dict[str, int] | None = None) -> dict:
    mean = sum(per_repeat) / len(per_repeat)
    rate = {"method": "abm", "task": task, "split": split, "per_repeat": per_repeat,
            "episodes": 25 * len(per_repeat), "errors": 0, "mean": mean,
            "std": statistics.pstdev(per_repeat)}
    if failures is not None:
        rate["failures"] = failures
    return rate


def _cells(run: str, split: str, per_repeat: list[float], tasks=TASKS, **extra) -> rep.Cells:
    return {(run, t, split): _rate(t, split, per_repeat, **extra) for t in tasks}


def _ctx(spec, cells: rep.Cells, tmp_path: Path, **outcomes) -> rep.Context:
    return rep.Context(spec, rep.Outcomes(cells=cells, **outcomes), Layout.of(spec, tmp_path, tmp_path / "out"))


def _section(spec, kind: str, table: int | None = None, nth: int = 0) -> Section:
    found = [s for s in (*spec.report.summary, *spec.report.details)
             if s.kind == kind and (table is None or s.table == table)]
    return found[nth]


# ------------------------------------------------------------------------------------------- spread
def test_the_standard_error_is_the_spread_of_the_repeat_wise_task_average() -> None:
    tasks = ("a", "b")
    cells = {("r", "a", "seen"): _rate("a", "seen", [40.0, 60.0, 80.0]),
             ("r", "b", "seen"): _rate("b", "seen", [20.0, 20.0, 50.0])}
    # repeat-wise averages over the tasks: 30, 40, 65 -> sample std 18.03, / sqrt(3)
    expected = statistics.stdev([30.0, 40.0, 65.0]) / math.sqrt(3)
    assert rep.standard_error(cells, "r", "seen", tasks) == pytest.approx(expected)
    assert rep.standard_error(cells, "r", "seen", ("a", "b", "c")) is None  # a task not evaluated yet
    assert rep.standard_error(cells, "r", "seen", ("a",)) == pytest.approx(20.0 / math.sqrt(3))  # std 20 of one task
    one = {("r", "a", "seen"): _rate("a", "seen", [50.0])}
    assert rep.standard_error(one, "r", "seen", ("a",)) is None  # one repeat: no spread to measure
    uneven = {**cells, ("r", "b", "seen"): _rate("b", "seen", [20.0, 20.0])}
    assert rep.standard_error(uneven, "r", "seen", tasks) is None  # repeats that do not line up


def test_spread_tables_show_each_average_with_its_standard_error_and_say_how(tmp_path: Path) -> None:
    cells = {**_cells("abm_clip", "seen", [60.0, 72.0, 84.0]), **_cells("abm_clip", "unseen", [40.0, 40.0, 40.0])}
    cells |= _cells("abm_clip", "compositional", [0.0, 20.0, 40.0], tasks=V2.split_tasks()["compositional"])
    ctx = _ctx(V2, cells, tmp_path)
    title, table, note = rep.write_section(ctx, _section(V2, "per_task", 1))
    average = next(line for line in table.splitlines() if line.startswith("| **average**"))
    # repeat-wise averages 60, 72, 84: sample std 12, standard error 12 / sqrt(3) = 6.9
    assert "| **–** | **72.0** ± 6.9 | **40.0** ± 0.0 | **–** |" in average
    assert "| close_jar | – | – | – | – | 72 ± 10 (54/75) | 40 ± 0 (30/75) |" in table  # cells: mean ± std
    assert note.startswith("± in a cell: the standard deviation of the task's success over the three repeats; ± "
                           "after an average: its standard error") and "divided by √3" in note
    _, t2, _ = rep.write_section(ctx, _section(V2, "per_run", 2))
    assert "| 20.0 ± 11.5 | 53.2 |" in t2  # 20 / sqrt(3)
    cells |= _cells("abm_clip_hash", "seen", [10.0, 20.0, 30.0])
    _, t3, _ = rep.write_section(_ctx(V2, cells, tmp_path), _section(V2, "averages", 3))
    assert "| center-pixel (abm_clip_hash) | 20.0 ± 5.8 | – | – | 70.0 | 57.5 |" in t3


def test_the_first_edition_renders_as_before_with_three_repeats(tmp_path: Path) -> None:
    """``spread`` is off in paper_tables: its averages show no ± and no note follows its tables."""
    cells = _cells("abm_clip", "seen", [60.0, 72.0, 84.0])
    ctx = _ctx(V1, cells, tmp_path)
    blocks = rep.write_section(ctx, _section(V1, "per_task", 1))
    assert len(blocks) == 2 and "| **average** | **–** | **–** | **–** | **–** | **72.0** | **–** |" in blocks[1]
    assert len(rep.write_section(ctx, _section(V1, "averages", 3))) == 2


# -------------------------------------------------------------------------------------------- seeds
def test_the_seed_spread_says_which_fusion_differences_exceed_it(tmp_path: Path) -> None:
    cells: rep.Cells = {}
    for run, seen, unseen in (("abm_clip_hash", 30.0, 20.0), ("abm_clip_hash_seed1", 26.0, 21.0),
                              ("stack", 40.0, 22.0), ("concat-rerendered", 31.0, 10.0), ("concat-full", 29.0, 20.5)):
        cells |= _cells(run, "seen", [seen] * 3) | _cells(run, "unseen", [unseen] * 3)
    table, text = rep.write_section(_ctx(V2, cells, tmp_path), _section(V2, "seeds"))
    assert table.splitlines()[0] == ("| run | other seed | seen avg | seen other seed | seen difference | unseen avg | "
                                     "unseen other seed | unseen difference |")
    assert table.splitlines()[2] == ("| center-pixel (abm_clip_hash) | abm_clip_hash_seed1 | 30.0 ± 0.0 | 26.0 ± 0.0 | "
                                     "4.0 | 20.0 ± 0.0 | 21.0 ± 0.0 | 1.0 |")
    # seen: spread 4; stack is 9-11 above the others; the other pairs differ by 2 or less
    assert ("seen: seed spread 4.0 points; differences between the table's rows larger than it: stack vs "
            "concat-rerendered 9.0, stack vs concat-full 11.0, stack vs center-pixel (abm_clip_hash) 10.0;") in text
    assert ("unseen: seed spread 1.0 points; differences between the table's rows larger than it: stack vs "
            "concat-rerendered 12.0, stack vs concat-full 1.5, stack vs center-pixel (abm_clip_hash) 2.0, "
            "concat-rerendered vs concat-full 10.5, concat-rerendered vs center-pixel (abm_clip_hash) 10.0.") in text
    # before the second seed is evaluated the spread is not claimed
    del cells[("abm_clip_hash_seed1", "close_jar", "seen")]
    _, text = rep.write_section(_ctx(V2, cells, tmp_path), _section(V2, "seeds"))
    assert "seen: the seed spread is not measured yet" in text and "unseen: seed spread 1.0 points" in text


# ---------------------------------------------------------------------------------------- diagnosis
def _kf(task: str, kind: str, cm: float, deg: float, chance: float | None = 45.0, split: str = "seen") -> dict:
    row = {"method": "abm", "task": task, "split": split, "kind": kind, "n": 5, "position_cm_median": cm,
           "within_grasp_tolerance": 0.5, "rotation_deg_median": deg, "gripper_agrees": 1.0}
    if chance is not None:
        row["yaw_chance_deg"] = chance
    return row


def _probe(own_cm: float, moved: dict[str, float]) -> dict:
    rows = [{"skill": "put X in the wine rack", "own": True, "n": 5, "position_cm_median": own_cm,
             "moved_cm_median": 0.0}]
    rows += [{"skill": s, "own": False, "n": 5, "position_cm_median": 20.0, "moved_cm_median": m}
             for s, m in moved.items()]
    return {"task": "place_wine", "kind": "move", "rows": rows}


SUMMARIES = {"abm_clip": [_kf("close_jar", "approach", 2.0, 40.0), _kf("place_food", "approach", 4.0, 44.0),
                          _kf("close_jar", "grasp", 1.0, 10.0), _kf("place_food", "grasp", 3.0, 12.0),
                          _kf("place_wine", "move", 25.0, 5.0, chance=0.0),
                          _kf("pick_block", "place", 9.0, 8.0, chance=22.5),
                          _kf("close_jar", "approach", 30.0, 80.0, split="unseen")],
             "abm_clip@oracle": [_kf("close_jar", "approach", 1.0, 20.0, chance=None)]}
PROBES = {("abm_clip", "place_wine"): _probe(26.3, {"close X": 1.3, "take X off the frypan": 31.3}),
          ("abm_clip", "pick_block"): _probe(1.5, {"close X": 41.0})}
FAILED = {"grasp missed": 40, "timeout": 10}


def test_the_diagnosis_shows_keyframes_beside_chance_the_probe_and_failure_reasons(tmp_path: Path) -> None:
    cells = _cells("abm_clip", "seen", [20.0, 20.0, 20.0], failures=FAILED)
    cells[("abm_clip", "close_jar", "seen")]["failures"] = {"grasp missed": 50, "IK unreachable": 10}
    ctx = _ctx(V2, cells, tmp_path, summaries=SUMMARIES, probes=PROBES)
    blocks = rep.write_section(ctx, _section(V2, "diagnosis"))
    assert blocks[0].startswith("Per model, what it gets wrong")
    seen = blocks[2].splitlines()
    assert seen[0] == "| model | approach | grasp | move | place |"  # kinds in keyframe order
    # medians over the tasks: approach 3.0 cm / 42° beside the two-fold chance 45°; a round move has chance 0
    assert seen[2] == "| abm_clip | 3.0 / 42 (45) | 2.0 / 11 (45) | 25.0 / 5 (0) | 9.0 / 8 (22.5) |"
    assert seen[3] == "| abm_clip@oracle | 1.0 / 20 | – | – | – |"  # an older diagnosis: no chance line
    assert "unseen objects" in blocks[3] and "| abm_clip | 30.0 / 80 (45) |" in blocks[4]
    probe = blocks[6].splitlines()
    assert probe[0] == "| model | place_wine | pick_block |"
    assert probe[2] == ("| abm_clip | 26.3 cm, not met (1 other text within 5 cm of it) | 1.5 cm, met (0 other "
                        "texts within 5 cm of it) |")
    failures = blocks[8].splitlines()
    assert failures[0] == "| model | split | failed / episodes | grasp missed | timeout | IK unreachable |"
    assert failures[2] == "| abm_clip | seen | 410 / 600 | 330 | 70 | 10 |"  # 7 tasks x 50 + 60, over 8 x 75
    assert rep.write_section(_ctx(V2, {}, tmp_path), _section(V2, "diagnosis")) == [blocks[0]]  # nothing yet


def test_a_missed_target_says_what_the_diagnosis_shows(tmp_path: Path) -> None:
    cells = _cells("abm_clip", "seen", [70.0, 60.0, 80.0]) | _cells("abm_clip", "unseen", [20.0] * 3, failures=FAILED)
    cells |= _cells("abm_oracle", "seen", [90.0] * 3)
    ctx = _ctx(V2, cells, tmp_path, summaries=SUMMARIES, probes=PROBES)
    (goals,) = rep.write_section(ctx, _section(V2, "targets"))
    assert "abm_clip: seen ≥ 60 %: met (70.0); unseen ≥ 0.85 × seen: not met (0.29)" in goals
    assert goals.startswith("Targets, abm with CLIP masks: ")  # no issue named in generated text
    # the explanation is a section of its own, written into the edition's page only
    section = _section(V2, "target_diagnosis")
    assert section.only == "document"
    (why,) = rep.write_section(ctx, section)  # abm_oracle meets its target: one paragraph
    assert why == ("Where a target is missed, the diagnosis shows: abm_clip (misses unseen ≥ 0.85 × seen): the "
                   "largest keyframe errors (seen objects) at move (25.0 cm, 5°) and place (9.0 cm, 8°); a rotation "
                   "no better than a random yaw's at approach (42° against 45°); the skill-text probe at the move "
                   "keyframe: place_wine's own text 26.3 cm from the expert's (not within 5 cm), pick_block's own "
                   "text 1.5 cm from the expert's (within 5 cm); its failed rollouts: grasp missed 320, timeout 80.")
    (oracle,) = rep.write_section(ctx, _section(V2, "targets", nth=1))
    assert oracle == "Target, abm with oracle masks: abm_oracle: seen ≥ 70 %: met (90.0)."
    # a run without any diagnosis says so
    cells |= _cells("abm_oracle", "seen", [50.0] * 3)
    whys = rep.write_section(_ctx(V2, cells, tmp_path), section)
    assert whys[-1].endswith("abm_oracle (misses seen ≥ 70 %): no diagnosis of it yet.")
    # met targets need no explanation
    met = _cells("abm_oracle", "seen", [90.0] * 3)
    assert rep.write_section(_ctx(V2, met, tmp_path), section) == []


def test_a_target_missed_by_less_than_the_seed_spread_says_so(tmp_path: Path) -> None:
    cells = _cells("abm_clip", "seen", [58.0] * 3) | _cells("abm_oracle", "seen", [61.0] * 3)
    cells |= _cells("rvt_clip", "unseen", [40.0] * 3) | _cells("abm_clip", "unseen", [55.0] * 3)
    section = _section(V2, "targets")
    (goals,) = rep.write_section(_ctx(V2, cells, tmp_path), section)
    assert "seen ≥ 60 %: not met (58.0);" in goals and "seed spread" not in goals  # no seed pair evaluated yet
    # center-pixel's two seeds 7 points apart on seen objects, 3 on unseen: the seed spread
    cells |= _cells("abm_clip_hash", "seen", [50.0] * 3) | _cells("abm_clip_hash_seed1", "seen", [57.0] * 3)
    cells |= _cells("abm_clip_hash", "unseen", [40.0] * 3) | _cells("abm_clip_hash_seed1", "unseen", [43.0] * 3)
    ctx = _ctx(V2, cells, tmp_path)
    assert rep.seed_spread(ctx) == {"seen": 7.0, "unseen": 3.0}
    (goals,) = rep.write_section(ctx, section)
    assert "abm_clip: seen ≥ 60 %: not met (58.0; 2.0 short, within the seed spread of 7.0 points);" in goals
    # unseen 55 against rvt's 40 + 20: 5 short, more than the unseen spread of 3: a measured miss
    assert "unseen ≥ rvt_clip unseen + 20: not met (55.0 vs 40.0);" in goals
    (oracle,) = rep.write_section(ctx, _section(V2, "targets", nth=1))
    assert "seen ≥ 70 %: not met (61.0; 9.0 short" not in oracle and "not met (61.0)." in oracle  # 9 > 7


def test_records_carry_the_failure_reasons_of_newer_evaluations(tmp_path: Path) -> None:
    cells = _cells("abm_clip", "seen", [20.0] * 3, failures=FAILED) | _cells("rvt_clip", "seen", [10.0] * 3)
    records = rep.records(V2, cells)
    assert {r["run"] for r in records if "failures" in r} == {"abm_clip"}
    assert next(r for r in records if r["run"] == "abm_clip")["failures"] == FAILED


def test_the_probes_are_kept_and_read_back(tmp_path: Path) -> None:
    layout = Layout.of(V2, tmp_path, tmp_path / "out")
    path = layout.skill_text("abm_oracle", "pick_block")
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(_probe(3.0, {})))
    assert rep.skill_text_probes(V2, layout) == {("abm_oracle", "pick_block"): _probe(3.0, {})}
    kept = {made: copy for made, copy in kept_pairs(V2, layout)}
    assert kept[path] == tmp_path / "docs/results/paper_tables_v2/skill_text_abm_oracle_pick_block.json"
    assert layout.skill_text("rvt_clip", "pick_block") not in kept  # rvt reads the whole instruction: not probed


# -------------------------------------------------------------------------------------------------- zoo
def _export(zoo: Path, name: str) -> None:
    zoo.mkdir(parents=True, exist_ok=True)
    (zoo / name).write_bytes(name.encode())


def test_both_editions_share_the_zoo_and_abm_zoo_eval_takes_the_newest(tmp_path: Path) -> None:
    zoo = tmp_path / "models"
    v1, v2 = Layout.of(V1, tmp_path), Layout.of(V2, tmp_path)
    assert v2.zoo_file("abm_clip") == zoo / "abm_clip_v2.pt" and v1.zoo_file("abm_clip") == zoo / "abm_clip.pt"
    for name in ("rvt_clip.pt", "abm_clip.pt", "abm_clip_hash.pt"):
        _export(zoo, name)
    (zoo / "benchmark-clip").mkdir()
    first = rep.zoo_index(V1, v1)
    (zoo / "index.json").write_text(json.dumps(first + [{"name": "benchmark-clip", "file": "benchmark-clip/",
                                                         "method": "clip", "sha256": "0" * 64}]))
    # the second edition exports abm_clip_hash before abm_clip: its entries still come in the spec's order
    _export(zoo, "abm_clip_hash_v2.pt")
    entries = rep.zoo_index(V2, v2)
    assert [e["name"] for e in entries] == ["rvt_clip", "abm_clip", "abm_clip_hash", "abm_clip_hash_v2"]
    assert entries[:3] == first  # the first edition's entries as they were
    new = entries[3]
    assert (new["file"], new["edition"], new["experiment"], new["run"], new["compared"]) == (
        "abm_clip_hash_v2.pt", 2, "paper_tables_v2", "abm_clip_hash", False)
    assert new["sha256"] == hashlib.sha256(b"abm_clip_hash_v2.pt").hexdigest()
    (zoo / "index.json").write_text(json.dumps(entries + [{"name": "benchmark-clip", "file": "benchmark-clip/",
                                                           "method": "clip", "sha256": "0" * 64}]))
    # without the new abm_clip, abm zoo eval keeps the first edition's (not the new abm_clip_hash)
    assert pick(read_index(zoo), "abm")["name"] == "abm_clip"
    for name in ("abm_clip_v2.pt", "rvt_clip_v2.pt"):
        _export(zoo, name)
    entries = rep.zoo_index(V2, v2)
    assert [e["name"] for e in entries] == ["rvt_clip", "abm_clip", "abm_clip_hash", "rvt_clip_v2", "abm_clip_v2",
                                            "abm_clip_hash_v2"]
    (zoo / "index.json").write_text(json.dumps(entries + [{"name": "benchmark-clip", "file": "benchmark-clip/",
                                                           "method": "clip", "sha256": "0" * 64}]))
    assert pick(read_index(zoo), "abm")["name"] == "abm_clip_v2"
    assert pick(read_index(zoo), "rvt")["name"] == "rvt_clip_v2"
    # each report describes its own models (the setup's recipe and minutes) and writes the whole index
    outcomes = rep.collect(V2, v2)
    assert [e["name"] for e in outcomes.entries] == ["rvt_clip_v2", "abm_clip_v2", "abm_clip_hash_v2"]
    assert outcomes.index is not None and len(outcomes.index) == 6
    for e in outcomes.entries:
        e.update(train_minutes=60.0, steps=6000, recipe={"preset": "small+custom", "resolution": 64, "patch_size": 8,
                                                         "rotation_crop": 16, "batch": 8, "optimizer": "adamw",
                                                         "lr": 0.001})
    (setup,) = rep.write_section(rep.Context(V2, outcomes, v2), _section(V2, "setup"))
    assert "at 64² views, patch 8, a 16-pixel rotation crop, 6000 steps of batch 8" in setup
    assert "Training minutes: rvt_clip 60.0, abm_clip 60.0, abm_clip_hash 60.0." in setup  # run names, this edition
    # the first edition's report keeps the second edition's entries (and the order), and leaves the zoo's README
    # to the newest edition
    again = rep.zoo_index(V1, v1)
    assert [e["name"] for e in again] == [e["name"] for e in entries]
    assert [e["name"] for e in rep.collect(V1, v1).entries] == ["rvt_clip", "abm_clip", "abm_clip_hash"]
    assert not rep.newest_edition(V1, again) and rep.newest_edition(V2, again)
    readme = rep.zoo_readme(V2, v2, again)
    assert "| name | edition | what | method |" in readme
    assert "| abm_clip | 1 | ABM (CLIP mask field, CLIP skill text) | abm |" in readme
    assert "| abm_clip_v2 | 2 | ABM (CLIP mask field, CLIP skill text) | abm |" in readme
    assert readme.splitlines()[2].startswith("Written by `abm experiment run paper_tables_v2`")
    # a model file that is gone leaves the index with the next report
    (zoo / "abm_clip_hash.pt").unlink()
    assert "abm_clip_hash" not in [e["name"] for e in rep.zoo_index(V2, v2)]


# ----------------------------------------------------------------------------------- headline, blocks
#: the headline the second edition wrote into the README until the third edition's gate opened (its text without
#: the seed-spread phrases): the third edition's section with the second's words
HEADLINE = replace(
    load_spec("paper_tables_v3").report.blocks["headline"][0], of_table=None,
    names={"abm_clip": "abm (CLIP mask field)", "rvt_clip": "rvt (CLIP text)"},
    text="**Result:** on objects it never saw, abm succeeds in {abm_clip_unseen} % of the episodes and the rvt "
         "baseline in {rvt_clip_unseen} % (the paper: {abm_clip_unseen_paper} % and {rvt_clip_unseen_paper} %); "
         "on the two compositional tasks no model was trained on, {abm_clip_compositional} % against "
         "{rvt_clip_compositional} % (the paper: {abm_clip_compositional_paper} % and "
         "{rvt_clip_compositional_paper} %).")


def test_the_headline_states_ours_beside_the_paper_once_every_number_is_measured(tmp_path: Path) -> None:
    section = HEADLINE
    comp = V2.split_tasks()["compositional"]
    cells: rep.Cells = {}
    for run, seen, unseen, composed in (("abm_clip", 60.0, 50.0, 70.0), ("rvt_clip", 40.0, 20.0, 10.0)):
        cells |= _cells(run, "seen", [seen] * 3) | _cells(run, "unseen", [unseen] * 3)
        cells |= _cells(run, "compositional", [composed] * 3, tasks=comp)
    text, table = rep.write_section(_ctx(V2, cells, tmp_path), section)
    assert text.startswith("**Result:** on objects it never saw, abm succeeds in 50.0 % of the episodes and the rvt "
                           "baseline in 20.0 % (the paper: 57.5 % and 24.0 %); on the two compositional tasks no "
                           "model was trained on, 70.0 % against 10.0 % (the paper: 53.2 % and 21.6 %).")
    assert table.splitlines() == ["| method | seen | unseen | compositional |", "|---|---|---|---|",
                                  "| abm (CLIP mask field), ours | 60.0 | 50.0 | 70.0 |",
                                  "| abm (CLIP mask field), paper | 70.0 | 57.5 | 53.2 |",
                                  "| rvt (CLIP text), ours | 40.0 | 20.0 | 10.0 |",
                                  "| rvt (CLIP text), paper | 74.2 | 24.0 | 21.6 |"]
    # a number not measured yet: no sentence claims it, the table shows –
    del cells[("rvt_clip", comp[0], "compositional")]
    (table,) = rep.write_section(_ctx(V2, cells, tmp_path), section)
    assert "| rvt (CLIP text), ours | 40.0 | 20.0 | – |" in table


def test_the_readme_block_leaves_the_diagnosis_to_the_page_and_the_dash_note_to_reports_with_dashes(
        tmp_path: Path) -> None:
    v3 = load_spec("paper_tables_v3")  # the edition that writes the README's blocks since its gate opened
    cells = _cells("abm_clip", "seen", [60.0] * 3) | _cells("abm_clip", "unseen", [20.0] * 3)
    outcomes = rep.Outcomes(cells=cells, summaries=SUMMARIES, probes=PROBES)
    written = rep.compose(v3, Layout.of(v3, tmp_path, tmp_path / "out"), outcomes)
    assert "Per model, what it gets wrong" in written.document and "## Diagnosis" in written.document
    assert "Where a target is missed" in written.document
    assert "Per model, what it gets wrong" not in written.block and "Where a target is missed" not in written.block
    assert "[the diagnosis](docs/results/paper_tables_v3.md#diagnosis)" in written.block
    assert "(paper_tables_v3.md#diagnosis)" not in written.document  # the readme-only link stays out of the page
    assert written.block.count("Reproduce: `abm experiment run paper_tables_v3`") == 1  # once, after the tables
    assert "cells not evaluated yet show –" in written.block.splitlines()[0]  # most cells are missing
    assert set(written.blocks) == {"headline"} and "| abm (CLIP mask fields), ours | 60.0 | 20.0 | – |" in (
        written.blocks["headline"])
    # the second edition writes no README block any more: its page, records and zoo index only
    assert not V2.report.readme and not V2.report.blocks
    assert not rep.shows_dash(["| a | 1.0 |\n|---|---|\n| b | 44.5–59.0 |"]) and rep.shows_dash(["| a | **–** |"])


def test_further_readme_blocks_are_checked_when_the_spec_is_loaded(tmp_path: Path) -> None:
    data = yaml.safe_load(load_spec("paper_tables_v3").path.read_text())
    data["report"].pop("readme_when")
    data["report"]["blocks"] = {"paper-tables": []}  # the block's own marker
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="report.blocks.paper-tables: expected a marker name"):
        load_spec(bad)
    data["report"]["blocks"] = {"headline": [{"kind": "headline", "runs": ["abm_clip"]}]}
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="needs its runs and splits"):
        load_spec(bad)
    data["report"]["summary"][0]["only"] = "somewhere"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError, match="only: expected one of readme, document, got 'somewhere'"):
        load_spec(bad)
