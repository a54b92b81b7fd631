"""Stopping a training whose curve is flat (abm.train.early_stop, TrainConfig.stop_when_flat): the rule on synthetic
curves, a tiny real training that stops early and is not continued, and the engine and the report taking it as
finished at the step it stopped."""

from __future__ import annotations

import json
import logging
import os
import subprocess
from pathlib import Path

import pytest
import torch

from abm.experiments.report.runs import describe_run, training_summary
from abm.experiments.stages import DONE, LEFT, Engine
from abm.policy.checkpoint import list_checkpoints, save_checkpoint
from abm.train import TrainConfig, train
from abm.train.early_stop import DEFAULT_TOLERANCE, FlatRule, FlatStop, flat_stop_in_log
from abm.train.synthetic import synthetic_episodes
from conftest import TINY_POLICY as TINY
from test_experiments import _spec
from test_train_distributed import _torchrun

FALLING = [(s, 10.0 * 0.999 ** s) for s in range(10, 2001, 10)]  # -10 % per 100 steps, for ever
# falling until step 1000, then flat (a small wobble around 3.0)
FLATTENING = [(s, 10.0 - 7.0 * s / 1000 if s <= 1000 else 3.0 + 0.01 * (-1) ** (s // 10)) for s in range(10, 2001, 10)]


def test_a_flat_curve_stops_at_the_first_checkpoint_whose_last_window_is_flat() -> None:
    rule = FlatRule(window=200, tolerance=0.02, first_step=0)
    stops = [s for s in range(100, 2001, 100) if rule.check(FLATTENING, s) is not None]
    # the window (1000, 1200] against (800, 1000]: 3.0 against a mean of ~4.0 at 1200, flat from 1400 on
    assert stops[0] == 1400 and stops == list(range(1400, 2001, 100))
    stop = rule.check(FLATTENING, 1400)
    assert stop is not None and stop.step == 1400 and stop.recent == pytest.approx(3.0, abs=0.01)
    assert stop.earlier == pytest.approx(3.0, abs=0.01) and abs(stop.improvement) < 0.02
    assert stop.to_dict()["stopped"] == "flat" and FlatStop.from_record(stop.to_dict()) == stop
    assert "stopped at step 1400" in stop.message() and "flat" in stop.message()


def test_a_falling_curve_trains_on_and_the_first_step_is_respected() -> None:
    assert all(FlatRule(200, 0.02, 0).check(FALLING, s) is None for s in range(100, 2001, 100))
    late = FlatRule(200, 0.02, first_step=1800)
    assert late.check(FLATTENING, 1700) is None and late.check(FLATTENING, 1800) is not None
    # two whole windows are needed before anything is compared
    assert FlatRule(1000, 0.6, 0).check(FLATTENING, 1900) is None
    assert FlatRule(1000, 0.6, 0).check(FLATTENING, 2000) is not None
    # a window without a logged row decides nothing
    assert FlatRule(5, 1.0, 0).check(FLATTENING, 1005) is None


def test_a_finished_log_tells_where_the_rule_would_have_stopped(tmp_path: Path) -> None:
    log = tmp_path / "log.csv"
    log.write_text("step,total,val_total\n" + "".join(f"{s},{v},\n" for s, v in FLATTENING))
    found = flat_stop_in_log(log, FlatRule(200, 0.02, 1000), checkpoint_every=250)
    assert found is not None and (found.step, found.loss) == (1500, "total")
    assert flat_stop_in_log(log, FlatRule(200, 0.02, 1000), checkpoint_every=3000) is None
    log.write_text("step,total,val_total\n" + "".join(f"{s},{v},{v if s % 250 == 0 else ''}\n" for s, v in FALLING))
    assert flat_stop_in_log(log, FlatRule(500, 0.02, 0), checkpoint_every=250) is None


def test_the_options_make_the_rule_and_stay_out_of_recipes_when_unset() -> None:
    base = dict(method="abm", out=Path("run"), steps=6000)
    assert TrainConfig(**base).flat_rule is None and "stop_when_flat" not in TrainConfig(**base).to_recipe()
    assert TrainConfig(**base, stop_when_flat=1000).flat_rule == FlatRule(1000, DEFAULT_TOLERANCE, 3000)
    assert TrainConfig(**base, stop_when_flat=500, flat_tolerance=0.1, flat_after=1000).flat_rule == FlatRule(
        500, 0.1, 1000)
    assert TrainConfig(**base, stop_when_flat=1000).to_recipe()["stop_when_flat"] == 1000


@pytest.fixture(scope="module")
def stopped_run(tmp_path_factory) -> tuple[Path, dict, list[int]]:
    """A tiny training of 12 steps that stops at step 6 (every window counts as flat: tolerance 1; not before 6)."""
    run = tmp_path_factory.mktemp("flat") / "run"
    cfg = TrainConfig(method="abm", out=run, steps=12, batch=2, checkpoint_every=2, log_every=5, policy=dict(TINY),
                      progress=False, warmup=2, lr=3e-3, stop_when_flat=2, flat_tolerance=1.0, flat_after=6)
    seen: list[int] = []
    summary = train(cfg, synthetic_episodes(3, camera_resolution=40), on_step=lambda s, _: seen.append(s))
    return run, summary, seen


def test_a_flat_training_stops_at_its_checkpoint_and_records_why(stopped_run) -> None:
    run, summary, seen = stopped_run
    assert seen == [1, 2, 3, 4, 5, 6] and summary["steps"] == 6 and summary["stopped"] == "flat"
    assert summary["flat"]["step"] == 6 and summary["flat"]["window"] == 2
    assert json.loads((run / "summary.json").read_text())["flat"] == summary["flat"]
    assert json.loads((run / "config.json").read_text())["flat"] == summary["flat"]
    assert [s for s, _ in list_checkpoints(run)][-1] == 6
    last = torch.load(run / "checkpoints/step_00000006.pt", weights_only=True)
    assert last["step"] == 6 and FlatStop.from_record(last) == FlatStop.from_record(summary)
    # every checkpoint is logged while the rule is on (log_every 5 alone would log step 5 only)
    rows = (run / "log.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == [2, 4, 5, 6]
    assert training_summary(run)["steps"] == 6 and describe_run(run)["steps"] == 6


def test_a_stopped_training_resumed_trains_no_further(stopped_run, caplog) -> None:
    run, summary, _ = stopped_run
    before = {p.name: p.stat().st_mtime_ns for _, p in list_checkpoints(run)}
    cfg = TrainConfig.from_dict({**json.loads((run / "config.json").read_text())["train"], "resume": True})
    seen: list[int] = []
    with caplog.at_level(logging.INFO, logger="abm.train.loop"):
        again = train(cfg, synthetic_episodes(3, camera_resolution=40), on_step=lambda s, _: seen.append(s))
    assert seen == [] and again == summary
    assert {p.name: p.stat().st_mtime_ns for _, p in list_checkpoints(run)} == before
    assert "is finished: it stopped at step 6" in caplog.text


def test_the_engine_takes_a_run_that_stopped_early_as_trained(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)  # its runs train 3 steps
    engine = Engine(spec, root=tmp_path)
    folder = engine.layout.run_dir("abm_oracle") / "checkpoints"
    folder.mkdir(parents=True)
    save_checkpoint(folder / "step_00000002.pt", {"step": 2})
    assert {j.id: j.state for j in engine.plan("train")}["train/abm_oracle"] == LEFT
    stop = FlatStop(2, 1.0, 1.0, 1, 0.02, "total")
    save_checkpoint(folder / "step_00000002.pt", {"step": 2, **stop.to_dict()})
    (engine.layout.run_dir("abm_oracle") / "log.csv").write_text("step,total\n1,1.0\n2,1.0\n")
    (job,) = [j for j in engine.plan("train") if j.id == "train/abm_oracle"]
    assert job.state == DONE and job.note == "2/3 steps: stopped, its curve flat"


@pytest.mark.slow
def test_every_rank_of_a_distributed_training_stops_at_the_same_checkpoint(tmp_path: Path) -> None:
    out = tmp_path / "run"
    cmd = _torchrun() + ["--standalone", "--nproc_per_node", "2", "-m", "abm.cli", "train", "--method", "abm",
                         "--synthetic", "3", "--camera-resolution", "32", "--steps", "12", "--batch", "1",
                         "--out", str(out), "--no-progress", "--checkpoint-every", "2", "--stop-when-flat", "2",
                         "--flat-tolerance", "1", "--flat-after", "6"]
    for key, value in TINY.items():
        cmd += ["--set", f"{key}={value}"]
    proc = subprocess.run(cmd, env=dict(os.environ, OMP_NUM_THREADS="1"), capture_output=True, text=True,
                          timeout=180)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world_size"] == 2 and summary["ranks_in_sync"]
    assert (summary["steps"], summary["stopped"], summary["flat"]["step"]) == (6, "flat", 6)
    assert "stopped at step 6: the training curve is flat" in proc.stdout + proc.stderr
