"""Success-table aggregation on made-up outcomes, and the resumable outcome log."""

import json
from dataclasses import replace

import pytest

from abm.evaluation.results import (
    EpisodeOutcome,
    OutcomeLog,
    aggregate,
    eval_seed,
    markdown_table,
    portable_path,
    write_csv,
    write_json,
)
from abm.evaluation.runner import EvalJob


def outcomes():
    out = []
    # abm / place_food / seen: repeat 0: 3 of 4, repeat 1: 1 of 4  -> 75, 25 -> mean 50, std 25
    for rep, wins in ((0, [1, 1, 1, 0]), (1, [0, 1, 0, 0])):
        for ep, w in enumerate(wins):
            out.append(EpisodeOutcome("abm", "place_food", "seen", rep, ep, eval_seed(rep, ep), bool(w)))
    # rvt / place_food / seen: always fails, one crash
    for rep in (0, 1):
        for ep in range(4):
            err = "boom" if (rep, ep) == (1, 2) else ""
            out.append(EpisodeOutcome("rvt", "place_food", "seen", rep, ep, eval_seed(rep, ep), False, error=err))
    # abm / pick_block / unseen: all succeed
    for rep in (0, 1):
        for ep in range(2):
            out.append(EpisodeOutcome("abm", "pick_block", "unseen", rep, ep, eval_seed(rep, ep), True))
    return out


def test_aggregate_means_and_stds():
    rates = {(r.method, r.task, r.split): r for r in aggregate(outcomes())}
    abm = rates[("abm", "place_food", "seen")]
    assert abm.per_repeat == [75.0, 25.0]
    assert abm.mean == pytest.approx(50.0) and abm.std == pytest.approx(25.0)
    rvt = rates[("rvt", "place_food", "seen")]
    assert rvt.mean == 0.0 and rvt.errors == 1 and rvt.episodes == 8
    assert rates[("abm", "pick_block", "unseen")].mean == 100.0


def test_markdown_table_layout():
    table = markdown_table(aggregate(outcomes()), splits=["seen", "unseen"])
    lines = table.splitlines()
    assert lines[0] == "**seen**"
    assert "| method | place_food | avg |" in lines
    assert "| abm | 50.0 ± 25.0 (4/8) | 50.0 |" in lines
    assert "| rvt | 0.0 ± 0.0 (0/8) | 0.0 |" in lines
    assert "**unseen**" in lines
    assert "| abm | 100.0 ± 0.0 (4/4) | 100.0 |" in lines
    one_repeat = [o for o in outcomes() if o.repeat == 0]
    assert "| abm | 75.0 (3/4) | 75.0 |" in markdown_table(aggregate(one_repeat)).splitlines()  # no "± 0.0"


def test_combined_table_over_splits():
    from abm.evaluation.results import combined_table

    lines = combined_table(aggregate(outcomes())).splitlines()
    assert lines[0] == ("| method | place_food seen | pick_block unseen | seen avg | unseen avg | unseen / seen |")
    assert lines[2] == "| abm | 50.0 ± 25.0 (4/8) | 100.0 ± 0.0 (4/4) | 50.0 | 100.0 | 2.00 |"
    assert lines[3] == "| rvt | 0.0 ± 0.0 (0/8) | – | 0.0 | – | – |"


def test_csv_and_json(tmp_path):
    rates = aggregate(outcomes())
    write_csv(rates, tmp_path / "t.csv")
    write_json(rates, tmp_path / "t.json")
    rows = (tmp_path / "t.csv").read_text().splitlines()
    assert rows[0] == "method,task,split,mean,std,repeats,episodes,errors"
    assert "abm,place_food,seen,50.00,25.00,2,8,0" in rows
    data = json.loads((tmp_path / "t.json").read_text())
    assert {d["method"] for d in data} == {"abm", "rvt"}


def test_log_round_trip_and_truncated_line(tmp_path):
    log = OutcomeLog(tmp_path / "outcomes.jsonl")
    for o in outcomes()[:3]:
        log.append(o)
    with log.path.open("a") as f:
        f.write('{"method": "abm", "task": "pla')  # killed mid-write
    read = log.read()
    assert len(read) == 3 and read[0] == outcomes()[0]
    assert ("abm", "place_food", "seen", 0, 2, "", "") in log.done()
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, False, error="RuntimeError: boom"))
    assert len(log.read()) == 4  # the record after the torn line is on a line of its own
    assert ("abm", "pick_block", "seen", 0, 0, "", "") not in log.done()  # crashed episodes are retried


def test_the_log_names_checkpoints_inside_the_working_folder_relative_to_it(tmp_path, monkeypatch):
    clone, elsewhere = tmp_path / "clone", tmp_path / "elsewhere"
    (clone / "models").mkdir(parents=True)
    monkeypatch.chdir(clone)
    log = OutcomeLog(clone / "eval" / "outcomes.jsonl")
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, True, checkpoint=str(clone / "models/m.pt")))
    log.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 1, 2, True, checkpoint=str(elsewhere / "m.pt")))
    inside, outside = (json.loads(line)["checkpoint"] for line in log.path.read_text().splitlines())
    assert inside == "models/m.pt" and outside == str(elsewhere / "m.pt")  # outside the folder: as given
    # an older log naming the absolute path is the same rollout as the relative name (resume does not redo it)
    old = EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, True, checkpoint=str(clone / "models/m.pt"))
    assert old.key == log.read()[0].key and old.key in log.done()
    assert portable_path("models/m.pt") == "models/m.pt" and portable_path("") == ""
    # the job that produces a rollout has its outcome's key, so resume skips it
    job = EvalJob("models/m.pt", "abm", "pick_block", "seen", 0, 0, 1, checkpoint=str(clone / "models/m.pt"))
    assert job.key in log.done() and replace(job, episode=2).key not in log.done()


def test_eval_seeds_are_shared_and_distinct():
    seeds = {eval_seed(r, e) for r in range(5) for e in range(25)}
    assert len(seeds) == 125 and min(seeds) >= 1_000_000
    with pytest.raises(ValueError, match="episode index"):
        eval_seed(0, 10_000)


def test_interrupted_evaluation_resumes_without_repeating(tmp_path):
    from abm.evaluation.runner import evaluate

    calls = []

    def fake_runner(job, settings):
        if len(calls) == 5 and not any(c == "interrupted" for c in calls):
            calls.append("interrupted")
            raise KeyboardInterrupt
        calls.append(job.key)
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed,
                              success=job.episode % 2 == 0, checkpoint=job.checkpoint, settings=job.settings)

    kwargs = dict(runs=["runA"], tasks=["t1", "t2"], split="seen", out_dir=tmp_path, episodes=3, repeats=2,
                  progress=False, labels={"runA": "abm"}, runner=fake_runner)
    with pytest.raises(KeyboardInterrupt):
        evaluate(**kwargs)
    assert len(OutcomeLog(tmp_path / "outcomes.jsonl").read()) == 5
    rates = evaluate(**kwargs)
    executed = [c for c in calls if c != "interrupted"]
    assert len(executed) == 12 and len(set(executed)) == 12  # every job exactly once over both runs
    assert [r.per_repeat for r in rates] == [[pytest.approx(200 / 3)] * 2] * 2
    assert (tmp_path / "results.md").read_text().startswith("**seen**")
    # other evaluation settings or other tasks would mix two protocols in one table: refused, nothing run
    from abm.evaluation.runner import EvalSettings

    calls.clear()
    kwargs["runner"] = lambda job, settings: EpisodeOutcome(
        job.method, job.task, job.split, job.repeat, job.episode, job.seed, True, checkpoint=job.checkpoint,
        settings=job.settings)
    with pytest.raises(ValueError, match="holds the outcomes of another evaluation .*settings"):
        evaluate(**kwargs, settings=EvalSettings(max_steps=3))
    with pytest.raises(ValueError, match=r"tasks t1 \(seen\), t2 \(seen\) there vs t1 \(seen\) now"):
        evaluate(**{**kwargs, "tasks": ["t1"]})
    assert len(OutcomeLog(tmp_path / "outcomes.jsonl").read()) == 12
    # in their own folder they run; more episodes in the same folder extend it
    rates = evaluate(**{**kwargs, "out_dir": tmp_path / "other"}, settings=EvalSettings(max_steps=3))
    assert [r.per_repeat for r in rates] == [[100.0, 100.0]] * 2
    rates = evaluate(**{**kwargs, "episodes": 4})
    assert [(r.successes, r.episodes) for r in rates] == [(6, 8)] * 2
    assert len(OutcomeLog(tmp_path / "outcomes.jsonl").read()) == 16


def test_crashed_episode_is_a_recorded_failure(tmp_path, monkeypatch):
    from abm.evaluation import runner

    def broken_policy(run, settings):
        raise RuntimeError("no checkpoint here")

    monkeypatch.setattr(runner, "_load_policy", broken_policy)
    job = runner.EvalJob("runA", "abm", "pick_block", "seen", 0, 0, eval_seed(0, 0))
    outcome = runner.run_job(job, runner.EvalSettings())
    assert outcome.success is False and "RuntimeError: no checkpoint here" in outcome.error


def test_eval_setup_errors_fail_before_any_rollout(tmp_path, capsys, monkeypatch, tiny_policy):
    """Setup mistakes are one clear error and a non-zero exit, never a table of zeros."""
    import torch

    from abm.cli import main as cli_main
    from abm.train import TrainConfig, train
    from abm.train.synthetic import synthetic_episodes

    run = tmp_path / "run"
    train(TrainConfig(method="abm", out=run, steps=1, batch=1, checkpoint_every=1, progress=False,
                      policy=tiny_policy), synthetic_episodes(1, camera_resolution=32))
    base = ["eval", "--run", str(run), "--episodes", "1", "--repeats", "1", "--workers", "1",
            "--out", str(tmp_path / "ev")]
    assert cli_main(base + ["--split", "compositional", "--tasks", "pick_block"]) == 2
    err = capsys.readouterr().err
    assert "pick_block has no objects in the 'compositional' split (it defines: seen, unseen)" in err
    if not torch.cuda.is_available():
        assert cli_main(base + ["--split", "seen", "--tasks", "pick_block", "--device", "cuda"]) == 2
        assert "CUDA is not available" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    args = ["eval", "--run", str(run), "--split", "seen", "--tasks", "pick_block", "--out", str(tmp_path / "file")]
    assert cli_main(args) == 2 and "is a file" in capsys.readouterr().err
    assert not (tmp_path / "ev").exists()  # nothing was rolled out
    # a run whose every episode crashes exits non-zero and shows the first error
    from abm.evaluation import runner

    def broken_policy(run, settings):
        raise RuntimeError("policy exploded")

    monkeypatch.setattr(runner, "_load_policy", broken_policy)
    assert cli_main(base + ["--split", "seen", "--tasks", "pick_block"]) == 2
    err = capsys.readouterr().err
    assert "1 of 1 episode(s) crashed and count as failures, every episode" in err
    assert "first error: " in err and "RuntimeError: policy exploded" in err


def test_failure_reasons_and_the_html_report(tmp_path) -> None:
    from abm.evaluation.html_report import gif_name, views_name, write_html_report
    from abm.evaluation.results import EpisodeOutcome, OutcomeLog, failure_reason

    assert failure_reason(True, "", ["unreachable"], False) == ""
    assert failure_reason(False, "boom", ["reached"], True) == "crashed"
    assert failure_reason(False, "", ["reached", "unreachable", "collided"], True) == "IK unreachable"
    assert failure_reason(False, "", ["reached", "blocked", "unreachable"], True) == "IK unreachable"
    assert failure_reason(False, "", ["blocked", "collided"], True) == "motion blocked"
    assert failure_reason(False, "", ["reached", "collided"], True) == "collision"
    assert failure_reason(False, "", ["reached"] * 3, False) == "grasp missed"
    assert failure_reason(False, "", ["reached"] * 3, True) == "timeout"
    outcomes = [EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 1, True, 5),
                EpisodeOutcome("abm", "pick_block", "seen", 0, 1, 2, False, 8, failure="grasp missed"),
                EpisodeOutcome("rvt", "pick_block", "seen", 0, 0, 1, False, 8, failure="timeout")]
    log = OutcomeLog(tmp_path / "outcomes.jsonl")
    log.path.write_text('{"method": "abm", "task": "t", "split": "seen", "repeat": 0, "episode": 0, "seed": 1, '
                        '"success": false}\n')  # a line written before failures were recorded
    assert log.read()[0].failure == ""
    gifs = tmp_path / "gifs"
    gifs.mkdir()
    for o in outcomes[:2]:
        (gifs / gif_name(o)).write_bytes(b"GIF89a")
    (gifs / views_name(outcomes[1])).write_bytes(b"PNG")
    page = write_html_report(outcomes, tmp_path / "report.html", gifs).read_text()
    assert page.count("_views.png") == 2 and "gifs/abm_pick_block_seen_001_views.png" in page  # link + image
    assert "<td>abm</td><td>pick_block</td><td>seen</td><td>50.0</td>" in page
    assert "<th>grasp missed</th>" in page and "<th>timeout</th>" in page
    assert page.count("<img ") == 3 and "src='gifs/abm_pick_block_seen_001.gif'" in page
    assert "http" not in page  # nothing fetched from the network
    assert "Success per target object" not in page  # outcomes recorded without their instruction
    # with the instruction and target recorded, captions show them and failures are traced to objects
    for o, target in zip(outcomes, ("red block", "teapot", "teapot"), strict=True):
        o.instruction, o.target = f"pick up the {target}", target
    log.path.unlink()
    for o in outcomes:
        log.append(o)
    assert [(o.instruction, o.target) for o in log.read()][1] == ("pick up the teapot", "teapot")
    page = write_html_report(log.read(), tmp_path / "report.html", gifs).read_text()
    assert "<i>pick up the teapot</i> (target: teapot)" in page
    assert "<td>abm</td><td>pick_block</td><td>seen</td><td>teapot</td><td>0/1</td>" in page
    assert "<td>abm</td><td>pick_block</td><td>seen</td><td>red block</td><td>1/1</td>" in page


def test_rollout_gif_frames_carry_instruction_step_and_result(tmp_path) -> None:
    from PIL import Image

    from abm.evaluation.runner import save_rollout_gif
    from abm.train.synthetic import synthetic_episodes

    episode = synthetic_episodes(1, camera_resolution=32)[0]
    path = tmp_path / "r.gif"
    save_rollout_gif(episode, path, result="grasp missed")
    plain = tmp_path / "plain.gif"
    episode.instruction = ""
    save_rollout_gif(episode, plain)
    with Image.open(path) as gif, Image.open(plain) as other:
        assert gif.n_frames == len(episode.steps) == 2
        # under the 64-px frame: the instruction wrapped to the width, the step and the result, one line each
        assert gif.size[1] >= 64 + 12 * 4 > other.size[1] == 64 + 12 * 3 + 4
        gif.seek(1)
        last = gif.convert("L")
        other.seek(1)
        assert max(last.crop((0, 64, gif.size[0], gif.size[1])).tobytes()) > 128  # white text on the black strip
        result = last.crop((0, gif.size[1] - 14, gif.size[0], gif.size[1])).tobytes()  # "grasp missed"
        assert max(result) > 128
        assert max(other.convert("L").crop((0, other.size[1] - 14, other.size[0], other.size[1])).tobytes()) < 128


def test_eval_command_defaults_to_trained_tasks_on_seen_and_unseen(tmp_path, capsys, caplog, monkeypatch,
                                                                   tiny_policy):
    """`abm eval --run RUN` evaluates the run's trained tasks on both splits into one combined table, refuses
    to append other tasks to those folders, and `--split seen --out DIR` keeps the single-folder layout."""
    import functools
    import shutil

    import abm.evaluation.session as command
    from abm.cli import main as cli_main
    from abm.evaluation import runner
    from abm.train import TrainConfig, train
    from abm.train.synthetic import synthetic_episodes

    run = tmp_path / "run"
    train(TrainConfig(method="abm", out=run, tasks=["pick_block"], steps=1, batch=1, checkpoint_every=1,
                      progress=False, policy=tiny_policy), synthetic_episodes(1, camera_resolution=32))

    def fake(job, settings):
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed,
                              job.episode == 0 or job.split == "seen", checkpoint=job.checkpoint,
                              settings=job.settings)

    monkeypatch.setattr(command, "evaluate_together", functools.partial(runner.evaluate_together, runner=fake,
                                                                        progress=False))
    assert cli_main(["eval", "--run", str(run), "--episodes", "2", "--repeats", "1", "--workers", "1"]) == 0
    out = capsys.readouterr()
    assert "tasks seen: pick_block; unseen: pick_block (trained on: pick_block" in caplog.text
    summary = (run / "eval_summary.md").read_text()
    assert "| abm | 100.0 (2/2) | 50.0 (1/2) | 100.0 | 50.0 | 0.50 |" in summary and summary.split("\n\n")[1] in out.out
    for split in ("seen", "unseen"):
        logged = OutcomeLog(run / f"eval_{split}" / "outcomes.jsonl").read()
        assert {(o.task, o.split) for o in logged} == {("pick_block", split)} and len(logged) == 2
    # another task set into the same folders is refused before any rollout
    assert cli_main(["eval", "--run", str(run), "--tasks", "place_food", "--episodes", "2", "--repeats", "1",
                     "--workers", "1"]) == 2
    assert "holds the outcomes of another evaluation" in capsys.readouterr().err
    assert len(OutcomeLog(run / "eval_seen" / "outcomes.jsonl").read()) == 2
    shutil.rmtree(run / "eval_seen")  # only eval_unseen conflicts now: still nothing runs, on any split
    assert cli_main(["eval", "--run", str(run), "--tasks", "place_food", "--episodes", "2", "--repeats", "1",
                     "--workers", "1"]) == 2
    assert not (run / "eval_seen").exists()
    # the scripts' explicit single-split form writes its tables straight into --out
    assert cli_main(["eval", "--run", str(run), "--split", "seen", "--episodes", "1", "--repeats", "1",
                     "--workers", "1", "--out", str(tmp_path / "ev")]) == 0
    assert json.loads((tmp_path / "ev" / "results.json").read_text())[0]["successes"] == 1


def test_rollouts_log_the_target_decision_of_every_step(shared_tiny_run):
    """A mask policy's outcome holds, per step, the decision ``abm run`` takes on the grounder's answer (the
    oracle finds the scene's target with confidence 1); evaluation acts either way."""
    from abm.evaluation import runner

    job = runner.EvalJob(str(shared_tiny_run), "abm", "pick_block", "seen", 0, 0, eval_seed(0, 0))
    outcome = runner.run_job(job, runner.EvalSettings(max_steps=2, resolution=32))
    assert outcome.error == "" and outcome.steps >= 1
    assert len(outcome.grounding) == outcome.steps
    first = outcome.grounding[0]
    assert set(first) == {"found", "confidence", "target", "reason"}
    assert first["found"] is True and first["confidence"] == 1.0 and first["target"] == outcome.target
