"""``abm experiment status`` beyond the jobs' states: the carried files with their sizes, a finished job's minutes
from what is kept when no job log of the working folder has them, and the estimated cost of what is left, each rate
with where it was measured."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest
from tests.test_experiments import TINY, _spec, _touch_checkpoint, _with

from abm.cli import main
from abm.evaluation.results import EpisodeOutcome, OutcomeLog, write_outcome_archive
from abm.experiments.stages import DONE, Engine
from abm.experiments.status import (
    carried_lines,
    diagnosis_rates,
    episode_rate,
    estimate,
    kept_minutes,
    not_estimated,
    step_rate,
)


def _carry_a_training(engine: Engine, run: str, step: int, elapsed_s: float) -> None:
    """A training carried at ``step`` after ``elapsed_s`` seconds (its checkpoint's bytes stand in for one)."""
    assert engine.layout.carry is not None
    folder = engine.layout.carry / run
    folder.mkdir(parents=True)
    (folder / f"step_{step:08d}.pt").write_bytes(b"x" * 2_500_000)
    (folder / "log.csv").write_text(f"step,total,elapsed_s\n1,9.0,{elapsed_s / 2}\n{step},8.0,{elapsed_s}\n")


def _outcomes(seconds: list[float]) -> list[EpisodeOutcome]:
    return [EpisodeOutcome("abm", "pick_block", "seen", 0, i, i, True, seconds=s) for i, s in enumerate(seconds)]


def test_the_status_names_every_carried_file_with_its_size(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    spec, path = _spec(tmp_path)
    engine = Engine(spec, root=tmp_path)
    assert carried_lines(engine.layout) == ["carried: nothing in models/carry"]
    _carry_a_training(engine, "abm_oracle", 2, 10.0)
    lines = carried_lines(engine.layout)
    assert lines[0] == "carried in models/carry (2 files, 2.5 MB):"
    assert lines[1:] == ["  abm_oracle/log.csv  0 kB", "  abm_oracle/step_00000002.pt  2.5 MB"]
    assert main(["experiment", "status", str(path), "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "abm_oracle/step_00000002.pt  2.5 MB" in out and "kept: nothing yet in docs/results/tiny/" in out


def test_the_estimate_multiplies_what_is_left_by_measured_rates_and_says_where_they_come_from(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)
    engine = Engine(spec, root=tmp_path)
    layout = engine.layout
    assert step_rate(spec, layout) is None and episode_rate(spec, layout) is None
    lines = estimate(spec, layout, engine.status())
    assert lines[0] == "estimate of what is left:"  # nothing measured: no minutes made up
    assert "  training: 2 job(s), 6 steps left: no speed measured yet" in lines
    _carry_a_training(engine, "abm_oracle", 2, 10.0)  # 5 s per step; 1 step left of 3
    (tmp_path / "docs/results").mkdir(parents=True)
    (tmp_path / "docs/results/rollout_speed.json").write_text(json.dumps(
        [{"commit": "old", "stage": "total", "seconds_per_rollout": 40.0},  # a baseline measured beside it
         {"commit": "new", "stage": "total", "seconds_per_rollout": 4.0},
         {"commit": "new", "stage": "total", "seconds_per_rollout": 6.0},
         {"commit": "new", "model": "m@tracking", "stage": "total", "seconds_per_rollout": 1.0},  # another protocol
         {"commit": "new", "stage": "render", "seconds_per_rollout": 100.0}]))
    lines = estimate(spec, layout, engine.status())
    assert lines[1] == ("  training: 2 job(s), 4 steps left × 5.00 s per step = 0.3 min (~0.2 min with 2 at a "
                        "time); measured from the training logs of abm_oracle")
    assert lines[2] == ("  evaluation: 2 job(s), 4 episodes left × 5.00 s per episode = 0.3 min (~0.3 min with 1 "
                        "worker(s)); measured from docs/results/rollout_speed.json (2 measurements at new)")
    assert lines[0] == "estimate of what is left: 0.7 min of CPU work"
    OutcomeLog(layout.eval_dir("abm_oracle", "seen") / "outcomes.jsonl").append(_outcomes([9.0])[0])
    rate = episode_rate(spec, layout)  # the spec's own episodes come first, and count as done
    assert rate is not None and rate.seconds == 9.0 and rate.source == "1 episodes evaluated by this spec"
    assert "3 episodes left × 9.00 s per episode" in estimate(spec, layout, engine.status())[2]


def test_a_finished_job_s_minutes_come_from_what_is_kept_on_a_fresh_clone(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)
    engine = Engine(spec, root=tmp_path)
    layout = engine.layout
    (tmp_path / "models").mkdir()
    (tmp_path / "models/abm_oracle.pt").write_bytes(b"model")  # exported: its training is done
    (tmp_path / "models/index.json").write_text(json.dumps([{"name": "abm_oracle", "train_minutes": 12.5,
                                                             "steps": 3}]))
    write_outcome_archive(_outcomes([30.0, 90.0]), layout.kept / "abm_oracle_seen_outcomes.jsonl.xz")
    (layout.kept / "abm_oracle_seen.json").write_text("[]")
    jobs = {j.id: j for j in engine.status()}
    assert jobs["train/abm_oracle"].state == DONE and jobs["train/abm_oracle"].minutes == 12.5
    assert jobs["eval/abm_oracle/seen"].state == DONE and jobs["eval/abm_oracle/seen"].minutes == 2.0
    assert jobs["train/rvt_clip"].minutes is None and kept_minutes(spec, layout, jobs["report"]) is None
    rate = step_rate(spec, layout)  # no training log: the finished runs' minutes
    assert rate is not None and rate.seconds == 250.0 and rate.source == "the minutes of the finished runs abm_oracle"


def test_a_spec_that_trained_nothing_yet_takes_the_rate_of_the_zoo_s_models_with_its_network_sizes(
        tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)
    layout = Engine(spec, root=tmp_path).layout
    config = spec.runs["abm_oracle"].config
    policy = config.policy
    recipe = {"batch": config.batch, "resolution": policy.resolution, "patch_size": policy.patch_size}
    if policy.rotation_crop:
        recipe["rotation_crop"] = policy.rotation_crop
    if policy.zoom_size:
        recipe |= {"zoom_size": policy.zoom_size, "zoom_resolution": policy.zoom_resolution,
                   "zoom_patch_size": policy.zoom_patch_size}
    (tmp_path / "models").mkdir()
    (tmp_path / "models/index.json").write_text(json.dumps([
        {"name": "earlier", "recipe": recipe, "train_minutes": 10.0, "steps": 100},  # 6 s per step
        {"name": "earlier_too", "recipe": recipe, "train_minutes": 20.0, "steps": 100},  # 12
        {"name": "bigger_views", "recipe": recipe | {"resolution": 2 * policy.resolution}, "train_minutes": 900.0,
         "steps": 100},
        {"name": "zoomed", "recipe": recipe | {"zoom_size": 0.3, "zoom_resolution": 32, "zoom_patch_size": 4},
         "train_minutes": 900.0, "steps": 100},
        {"name": "never_trained", "recipe": recipe, "steps": 100},
    ]))
    rate = step_rate(spec, layout)
    assert rate is not None and rate.seconds == 9.0, rate
    assert rate.source == "the zoo's models with this spec's network sizes: earlier, earlier_too"
    _carry_a_training(Engine(spec, root=tmp_path), "abm_oracle", 2, 10.0)  # its own log comes first
    assert step_rate(spec, layout) is not None and step_rate(spec, layout).seconds == 5.0


def test_the_carry_stage_removes_a_carried_training_once_its_evaluations_are_kept(tmp_path: Path) -> None:
    data = _with(runs={"abm_oracle": TINY["runs"]["abm_oracle"]}, evaluation__from_zoo=False,
                 report__summary=[{"kind": "per_task", "table": 1, "runs": ["abm_oracle"], "splits": ["seen"]}])
    for key in ("clip", "zoo"):
        data.pop(key)
    spec, _ = _spec(tmp_path, data)
    engine = Engine(spec, root=tmp_path)
    _touch_checkpoint(engine.layout, "abm_oracle", 3)  # trained, not evaluated yet: its evaluation needs it
    assert engine.served() == [] and engine.carry(strict=True) == ["abm_oracle"]
    carried = tmp_path / "models/carry/abm_oracle"
    assert (carried / "step_00000003.pt").is_file()
    (engine.layout.kept / "abm_oracle_seen.json").parent.mkdir(parents=True)
    (engine.layout.kept / "abm_oracle_seen.json").write_text("[]")  # its only evaluation is kept
    assert engine.served() == ["abm_oracle"]
    assert engine.carry(strict=True) == [] and not carried.exists()  # removed, not carried again


def test_the_jobs_without_an_estimate_are_counted_past_three_of_a_stage() -> None:
    diagnoses = [f"diagnose/run{i}" for i in range(36)]
    assert not_estimated(["data", "ground/masks", "ground/features", "eval/zoo", *diagnoses]) == (
        "data, ground/masks, ground/features, eval/zoo, diagnose/run0, diagnose/run1, diagnose/run2 and 33 more "
        "diagnose jobs")
    assert not_estimated(diagnoses[:4]) == "diagnose/run0, diagnose/run1, diagnose/run2, diagnose/run3"  # 1 more


@dataclass
class _Job:
    id: str
    stage: str
    state: str
    minutes: float | None = None


def test_the_diagnosis_left_is_estimated_from_the_finished_jobs_of_its_kind(tmp_path: Path) -> None:
    spec, _ = _spec(tmp_path)
    layout = Engine(spec, root=tmp_path).layout
    jobs = [_Job("diagnose/a", "diagnose", "done", 3.0), _Job("diagnose/b@oracle", "diagnose", "done", 5.0),
            _Job("diagnose/c", "diagnose", "left"), _Job("diagnose/d@oracle", "diagnose", "running", 1.0),
            _Job("diagnose/skill_text/a/pick_block", "diagnose", "left"),
            _Job("diagnose/destination_grounding", "diagnose", "left")]
    rates = diagnosis_rates(jobs)
    assert set(rates) == {"keyframe accuracy"} and rates["keyframe accuracy"].seconds == 240.0  # (3 + 5) / 2 min
    lines = estimate(spec, layout, jobs)
    assert lines[0] == "estimate of what is left: 8.0 min of CPU work"
    assert lines[1] == ("  diagnosis (keyframe accuracy): 2 job(s), 2 jobs left × 240.00 s per job = 8.0 min (~4.0 "
                        "min with 2 at a time); measured from 2 finished keyframe accuracy job(s) of this spec")
    # kinds with nothing finished yet stay unestimated, by name
    assert lines[2] == "  not estimated: diagnose/skill_text/a/pick_block, diagnose/destination_grounding"
