"""An edition's time per stage in ``abm experiment status`` (issue 54 item 6: the wall time of every stage, every
session added up, and the jobs' own minutes) and its per-episode outcomes kept for every evaluation cell, the
timed zoo evaluation's too (item 3)."""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

import pytest

from abm.cli import main
from abm.evaluation.results import OUTCOME_ARCHIVE
from abm.evaluation.settings import ZOO_EVAL_SPLITS
from abm.experiments.spec import load_spec
from abm.experiments.stages import Engine
from abm.experiments.state import Layout, keep, kept_pairs, restore, stage_minutes
from abm.experiments.status import stage_time_lines

V3 = load_spec("paper_tables_v3")
HOST = socket.gethostname()


def _jobs_log(layout: Layout, spans: list[tuple[str, float, float]]) -> None:
    """OUT/jobs.jsonl with one start and one end per ``(job, start, end)`` (seconds), as the engine logs them."""
    layout.out.mkdir(parents=True, exist_ok=True)
    lines = []
    for job, start, end in spans:
        lines.append({"job": job, "event": "start", "time": start, "host": "elsewhere", "pid": 7, "backend": "local"})
        lines.append({"job": job, "event": "end", "time": end, "host": "elsewhere", "rc": 0})
    layout.jobs.write_text("".join(json.dumps(line) + "\n" for line in lines))


def test_the_status_adds_up_every_stage_and_its_jobs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    engine = Engine(V3, root=tmp_path)
    layout = engine.layout
    assert stage_time_lines(layout, engine.status()) == ["wall time per stage: no stage has run yet"]
    # two sessions of training (90 + 30 min of stage time, two trainings side by side in the first: 150 job
    # minutes), one of data; an earlier session's evaluation, kept (KEPT/times.txt), 60 min
    layout.out.mkdir(parents=True)
    layout.times.write_text("data_start 0 a:1\ndata_end 600 a:1\ntrain_start 600 a:1\ntrain_end 6000 a:1\n"
                            "train_start 10000 b:2\ntrain_end 11800 b:2\n")
    layout.kept.mkdir(parents=True)
    (layout.kept / "times.txt").write_text("data_start 0 a:1\ndata_end 600 a:1\neval_start 20000 c:3\n"
                                           "eval_end 23600 c:3\n")
    _jobs_log(layout, [("data", 0, 600), ("train/abm_clip", 600, 6000), ("train/rvt_clip", 600, 2400),
                       ("train/rvt_clip", 10000, 11800)])
    lines = stage_time_lines(layout, engine.status())
    assert lines[0] == ("wall time per stage, every session added up (min): data 10, train 120, eval 60; 190 in all")
    assert lines[1] == ("job time per stage, each job's own minutes added up (min): data 10 (1 job), train 150 "
                        "(2 jobs)")
    assert stage_minutes(layout.times) == {"data": 10.0, "train": 120.0}  # the report's: OUT's alone, as before
    assert main(["experiment", "status", "paper_tables_v3", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert lines[0] in out and lines[1] in out and out.index(lines[0]) < out.index("kept: ")


def test_a_stage_running_now_counts_up_to_now(tmp_path: Path) -> None:
    layout = Layout.of(V3, tmp_path)
    layout.out.mkdir(parents=True)
    now = int(time.time())
    layout.times.write_text(f"eval_start {now - 1200} {HOST}:{os.getpid()}\n"  # this live engine: 20 min so far
                            f"diagnose_start {now - 600} {HOST}:999999999\n")  # a killed engine's: not counted
    (line, *_) = stage_time_lines(layout, [])
    assert line == "wall time per stage, every session added up (min): eval 20 (running); 20 in all"


def test_every_cell_keeps_its_episodes_step_by_step_and_so_does_the_zoo_eval(tmp_path: Path) -> None:
    layout = Layout.of(V3, tmp_path)
    kept = dict(kept_pairs(V3, layout))
    cells = [(name, split.split) for split in V3.evaluation.splits for name in V3.evaluation.split_runs(
        split, list(V3.runs))]
    assert len(cells) == 27 and ("abm_oracle", "compositional") in cells
    for name, split in cells:  # every cell, compositional too, from the zoo files
        assert kept[layout.eval_dir(name, split) / OUTCOME_ARCHIVE] == layout.kept / f"{name}_{split}_{OUTCOME_ARCHIVE}"
    for split in ZOO_EVAL_SPLITS:  # the timed abm zoo eval writes ZOO_EVAL/SPLIT/outcomes.jsonl.xz
        archive = layout.zoo_eval / split / OUTCOME_ARCHIVE
        assert kept[archive] == layout.kept / f"zoo_eval_{split}_{OUTCOME_ARCHIVE}"
        archive.parent.mkdir(parents=True)
        archive.write_bytes(split.encode())
    assert keep(V3, layout) == 2
    for split in ZOO_EVAL_SPLITS:
        (layout.zoo_eval / split / OUTCOME_ARCHIVE).unlink()
    assert restore(V3, layout) == 2 and (layout.zoo_eval / "seen" / OUTCOME_ARCHIVE).read_bytes() == b"seen"
