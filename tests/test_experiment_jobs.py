"""Typed jobs (abm.experiments.jobs): every kind round-trips through its job file, names the ``abm`` command that
does the same (abm's own parser reads it back into the same values, so a renamed flag fails here), and the job
process reports a mistake in one ``abm: error:`` line, as ``abm`` does."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from abm.cli import build_parser
from abm.cli.commands.evaluate import eval_request
from abm.configuration import apply_config_file
from abm.errors import ConfigError
from abm.evaluation.diagnose.keyframe_accuracy import KeyframeAccuracy
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.evaluation.session import EvalRequest
from abm.evaluation.settings import ZOO_EVAL_TASKS, EvalSettings
from abm.experiments.jobs import (
    JOBS,
    DataJob,
    DiagnoseJob,
    EvaluationJob,
    ExportJob,
    GroundJob,
    TrainJob,
    ZooEvalJob,
    read_job,
)
from abm.train.config import TrainConfig

EVAL = EvaluationJob(EvalRequest((Path("models/abm_clip.pt"),), tasks=("pick_block", "place_food"), splits=("unseen",),
                           episodes=3, repeats=2, workers=1, gifs=2, out=Path("runs/x/eval/abm_clip/unseen"),
                           settings=EvalSettings(grounder="clip", resolution=64, max_steps=6,
                                                 clip_model="models/benchmark-clip", expert_keyframes="move")))
JOBS_OF_EVERY_KIND = [
    DataJob(("pick_block", "place_food"), "seen", 20, Path("runs/x/data"), workers=2, seed=3, resolution=64,
            backend="ray", ray_address="10.0.0.1:6379"),
    GroundJob(Path("runs/x/data"), Path("runs/x/cache_features"), "models/benchmark-clip", ("pick_block",),
              features=True, workspace_center=(0.5, 0.0, 0.15), workspace_size=0.6),
    TrainJob(TrainConfig(method="rvt", out=Path("runs/x/rvt"), data=Path("runs/x/data"), steps=7, resume=True,
                         progress=False), Path("runs/x/recipes/rvt.yaml")),
    ExportJob(Path("runs/x/rvt"), Path("models/rvt.pt"), "bfloat16"),
    EVAL,
    ZooEvalJob(Path("models"), Path("runs/x/zoo_eval"), episodes=2, models=("abm_clip_v3", "rvt_clip_v3")),
    DiagnoseJob(KeyframeAccuracy((Path("models/abm_clip.pt"),), ("pick_block",), Path("runs/x/ka.json"),
                                 steps=(1000, 2000), grounder="oracle")),
    DiagnoseJob(SkillTextProbe(Path("models/abm_clip.pt"), "pick_block", ("pick_block", "place_food"),
                               Path("runs/x/st.json"), episodes=2)),
]


def test_every_kind_is_registered_and_tested() -> None:
    assert sorted(JOBS) == sorted({type(job).kind for job in JOBS_OF_EVERY_KIND})


@pytest.mark.parametrize("job", JOBS_OF_EVERY_KIND, ids=lambda job: type(job).kind)
def test_a_job_round_trips_through_its_file(job, tmp_path: Path) -> None:
    job.write(tmp_path / "jobs" / "a.json")
    again = read_job(tmp_path / "jobs" / "a.json")
    assert again == job and type(again) is type(job)


def test_a_job_file_that_is_not_one_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "job.json"
    for text, message in (('{"kind": "sleep"}', "unknown job kind 'sleep'; choose from data, ground"),
                          ('{"kind": "export", "run_dir": "r", "out": "o", "speed": 2}', "not a job of kind 'export'"),
                          ('{"kind": "export", "out": "o"}', "a job of kind 'export': .*run_dir"),
                          ("[1]", "not a job file"), ("{", "not a job file")):
        path.write_text(text)
        with pytest.raises(ConfigError, match=message):
            read_job(path)


def _parsed(job):
    return build_parser().parse_args(job.command())


def test_each_command_is_one_abm_reads_back_into_the_job_s_values() -> None:
    data, ground, trained, export, _, zoo, keyframes, _ = JOBS_OF_EVERY_KIND
    args = _parsed(data)
    assert (args.task, args.split, args.episodes, args.out, args.workers, args.seed, args.resolution, args.backend,
            args.ray_address) == ("pick_block,place_food", "seen", 20, Path("runs/x/data"), 2, 3, 64, "ray",
                                  "10.0.0.1:6379")
    args = _parsed(ground)
    assert (args.data, args.cache, args.clip_model, args.features, args.tasks, args.workspace_center,
            args.workspace_size) == (Path("runs/x/data"), Path("runs/x/cache_features"), "models/benchmark-clip",
                                     True, ["pick_block"], [0.5, 0.0, 0.15], 0.6)
    assert ground.workspace().center == (0.5, 0.0, 0.15) and ground.workspace().size == 0.6
    assert trained.command()[:3] == ["train", "--config", "runs/x/recipes/rvt.yaml"]
    args = _parsed(export)
    assert (args.run, args.out, args.dtype) == ("runs/x/rvt", "models/rvt.pt", "bfloat16")
    assert eval_request(_parsed(EVAL)) == EVAL.request  # the request abm eval builds from those flags
    args = _parsed(zoo)
    assert (args.zoo, args.out, args.tasks, args.episodes) == (Path("models"), Path("runs/x/zoo_eval"),
                                                              list(ZOO_EVAL_TASKS), 2)
    assert keyframes.command() is None  # no abm command: the engine's dry run prints the job itself


def test_a_training_s_command_reads_its_recipe(tmp_path: Path) -> None:
    """The recipe the engine writes beside a training (its config as ``abm train --config`` reads it) and the
    command together are that training."""
    trained = JOBS_OF_EVERY_KIND[2]
    recipe = tmp_path / "rvt.yaml"
    recipe.write_text(yaml.safe_dump(trained.config.to_recipe(), sort_keys=False))
    words = ["train", "--config", str(recipe), *trained.command()[3:]]
    parser = build_parser()
    apply_config_file(parser, words)
    args = parser.parse_args(words)
    assert (args.method, args.steps, args.data, args.out, args.resume, args.progress) == (
        "rvt", 7, Path("runs/x/data"), Path("runs/x/rvt"), True, False)


def test_the_job_process_says_a_mistake_in_one_line(tmp_path: Path) -> None:
    job = tmp_path / "jobs" / "export.json"
    ExportJob(tmp_path / "no_run", tmp_path / "zoo" / "a.pt").write(job)
    done = subprocess.run([sys.executable, "-m", "abm.experiments.jobs", str(job)], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2 and done.stderr.splitlines()[-1].startswith("abm: error: "), done.stderr
    assert str(tmp_path / "no_run") in done.stderr and not (tmp_path / "zoo").exists()
    (tmp_path / "jobs" / "bad.json").write_text('{"kind": "data"}')
    done = subprocess.run([sys.executable, "-m", "abm.experiments.jobs", str(tmp_path / "jobs" / "bad.json")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and done.stderr.startswith("abm: error: a job of kind 'data': "), done.stderr
