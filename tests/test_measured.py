"""The first hour's measurements (abm.measured, benchmarks/first_hour.py): parsed from real tool output, counted
from outcome files, and the README / docs blocks the same as the committed measurement file makes them."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from abm import measured
from abm.experiments.report.pages import first_hour

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("first_hour_script", ROOT / "benchmarks" / "first_hour.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


TIME_V = """\tCommand being timed: "abm quickstart"
\tUser time (seconds): 2400.50
\tSystem time (seconds): 59.50
\tPercent of CPU this job got: 180%
\tElapsed (wall clock) time (h:mm:ss or m:ss): 1:02:03
\tMaximum resident set size (kbytes): 2000000
"""


def _outcomes(folder: Path, rows: list[tuple[str, str, str, int, bool, str]]) -> None:
    for method, split, task, episode, success, digest in rows:
        path = folder / split / "outcomes.jsonl"
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as f:
            f.write(json.dumps({"method": method, "task": task, "split": split, "repeat": 0, "episode": episode,
                                "seed": 1000 + episode, "success": success, "trajectory": digest}) + "\n")


def test_wall_and_cpu_minutes_from_usr_bin_time(script, tmp_path: Path) -> None:
    (tmp_path / "t.txt").write_text(TIME_V)
    assert script.time_file(tmp_path / "t.txt") == (62.0, 41.0)  # 1 h 2 min 3 s; (2400.5 + 59.5) / 60


def test_results_and_episodes_that_flip_across_cpus(script, tmp_path: Path) -> None:
    rows = [("abm", "seen", "pick_block", 0, True, "a"), ("abm", "seen", "pick_block", 1, False, "b"),
            ("abm", "unseen", "pick_block", 0, True, "c"), ("rvt", "seen", "place_wine", 0, False, "d")]
    _outcomes(tmp_path / "default", rows)
    flipped = [rows[0][:4] + (False, "x"), rows[1][:4] + (True, "y"), rows[2], rows[3][:5] + ("z",)]
    _outcomes(tmp_path / "avx2", flipped)
    assert script.results(script.outcomes(tmp_path / "default")) == {
        "abm": {"seen": [1, 2], "unseen": [1, 1]}, "rvt": {"seen": [0, 1]}}
    c = script.cross_cpu(tmp_path / "default", tmp_path / "avx2", "test machine")
    assert (c["episodes"], c["differing"], c["cells"], c["cells_differing"], c["max_per_cell"],
            c["identical_trajectories"]) == (4, 2, 3, 1, 2, 1)
    _outcomes(tmp_path / "fewer", rows[:3])
    with pytest.raises(SystemExit, match="different episodes"):
        script.cross_cpu(tmp_path / "default", tmp_path / "fewer", "test machine")


def test_the_sentences_say_what_was_measured(monkeypatch: pytest.MonkeyPatch) -> None:
    data = {"quickstart": {"wall_minutes": 31.4, "cpu_minutes": 55.0, "machine": "M, 2 cores", "date": "2026-11-28",
                           "commit": "abc1234", "grounder": "benchmark CLIP", "load": "nothing else ran",
                           "results": {"abm": {"seen": [6, 10], "unseen": [5, 10]}, "rvt": {"seen": [2, 10],
                                                                                         "unseen": [0, 10]}}},
            "cross_cpu": {"kernels": "AVX2", "episodes": 160, "differing": 7, "cells": 32, "cells_differing": 6,
                          "max_per_cell": 2, "identical_trajectories": 0, "machine": "M, 2 cores"}}
    monkeypatch.setattr(measured, "measured", lambda: data)
    text = measured.quickstart_text()
    assert "31 min wall (55 min of CPU)" in text and "abm 6/10 seen, 5/10 unseen; rvt 2/10 seen, 0/10 unseen" in text
    assert "7 of 160 episodes" in measured.reproducibility_text()
    assert measured.zoo_eval_text() == "not measured yet" and measured.tests_text() == "not measured yet"
    block = first_hour.quickstart_block()
    assert "| | abm seen | abm unseen | rvt seen | rvt unseen | wall | CPU |" in block
    assert "| defaults | 6/10 | 5/10 | 2/10 | 0/10 | 31.4 min | 55.0 min |" in block


def test_the_committed_blocks_are_what_the_committed_measurements_make(tmp_path: Path) -> None:
    for name in ("README.md", "docs/evaluation.md"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text((ROOT / name).read_text())
    assert first_hour.write(tmp_path) == []  # nothing to change: the committed blocks are generated


def test_the_help_texts_state_the_measurement() -> None:
    from abm.cli import build_parser

    parser = build_parser()
    quick = parser._subparsers._group_actions[0].choices["quickstart"]  # noqa: SLF001 - argparse has no getter
    assert " ".join(quick.format_help().split()).count(" ".join(measured.quickstart_text().split())[:40]) == 1


def test_zoo_eval_points_at_its_models_edition_page() -> None:
    from abm.evaluation.session import edition_page
    from abm.zoo import edition, read_index

    # the editions abm zoo eval can run: the first's, and those whose models are compared (a gated edition's page
    # is written with its tables, when its gate opens)
    editions = {edition(e) for e in read_index(ROOT / "models")
                if e.get("method") and (edition(e) == 1 or e.get("compared") is True)}
    assert editions >= {1, 2}
    for number in editions:
        assert (ROOT / edition_page(number)).is_file()
    assert edition_page(2) == "docs/results/paper_tables_v2.md"


RENDER_OUT = """device: cpu (M, 2 cores)
| points | batch | ms / call | ms / sample |
|---|---|---|---|
| 50k | 1 | 16.2 | 16.2 |
| 100k | 1 | 24.6 | 24.6 |
| 200k | 1 | 44.3 | 44.3 |
| 50k | 8 | 181.1 | 22.6 |
"""
GROUNDING_OUT = """device: cpu (M); 4 cameras at 128x128, 42368 points
| model | input | dtype | image encoder (s) | text (s) | mask field, total (s) | mask -> 5 views (s) |
|---|---|---|---|---|---|---|
| vit-b16 | 224x224 | float32 | 0.612 | 0.051 | 0.734 | 0.020 |
"""
GENERATION_OUT = """
2 worker(s), 128x128, 4 cameras

| task | episodes | seconds | episodes/min | MB/episode |
|---|---|---|---|---|
| pick_block | 6 | 21 | 17.1 | 1.20 |
| put_in_shelf | 6 | 40 | 9.0 | 2.31 |
"""


def test_the_speed_commands_outputs_are_parsed(script) -> None:
    assert script.render_ms(RENDER_OUT) == 24.6  # the 100k-point, batch-1 row, not the 50k one before it
    assert script.mask_field_s(GROUNDING_OUT) == 0.734  # the total column, not the encoder's
    assert script.generation_range(GENERATION_OUT) == [9.0, 17.1]
    policy = "\n".join([json.dumps({"preset": "small", "device": "cpu", "median_s": 0.05, "parameters": 2_000_000}),
                        json.dumps({"device": "cuda", "skipped": "CUDA not available"}),
                        json.dumps({"preset": "paper", "device": "cpu", "median_s": 0.9, "parameters": 30_800_000})])
    assert script.policy_step(policy) == {"policy_small_s": 0.05, "policy_paper_s": 0.9, "paper_parameters": 30_800_000}
    assert script.train_samples_per_s('warming up\n{"samples_per_s": 12.5, "threads": 1}\n') == 12.5
    with pytest.raises(SystemExit, match="100k"):
        script.render_ms(RENDER_OUT.replace("| 100k |", "| 120k |"))
    with pytest.raises(SystemExit, match="not small and paper"):
        script.policy_step(policy.splitlines()[0])


def test_a_failing_speed_command_stops_with_its_error(script) -> None:
    with pytest.raises(SystemExit, match="no_such_benchmark.py' failed"):
        script.speed(["python benchmarks/no_such_benchmark.py"])


def test_the_speed_table_is_made_from_the_measurement(script, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(measured, "measured", lambda: {})
    assert "not measured yet" in first_hour.speed_block()
    values = {"render_ms": 24.6, "policy_small_s": 0.05, "policy_paper_s": 0.9, "paper_parameters": 30_800_000,
              "mask_field_s": 0.734, "train_samples_per_s": 12.5, "generation_episodes_per_min": [9.0, 17.1],
              "machine": "M, 2 cores", "date": "2026-11-30", "commit": "abc1234"}
    monkeypatch.setattr(measured, "measured", lambda: {"speed": values})
    block = first_hour.speed_block()
    assert "on M, 2 cores, 2026-11-30, at abc1234" in block
    assert "| `python benchmarks/render_speed.py` | 24.6 ms | — |" in block
    assert "| same | 0.90 s (1.11 FPS; 30.8 M parameters) | 0.68 FPS |" in block
    assert "0.05 s (20.0 FPS)" in block and "0.73 s" in block and "12.5 samples/s" in block
    assert "9–17 episodes/min (by task)" in block
    # every command the table shows is one the recorder knows how to read
    commands = [r.command.split()[1] for r in first_hour.SPEED_ROWS if r.command]
    assert sorted(commands) == sorted(script.SPEED_PARSERS)
