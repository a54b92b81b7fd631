"""The one progress reporter: bars on a terminal, a few plain lines in logs; and what abm train logs."""

from __future__ import annotations

import csv
import io

from abm.progress import Progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_plain_lines_in_a_log_at_most_one_per_tenth() -> None:
    out = io.StringIO()  # not a terminal: a log file, a pipe, CI
    with Progress(1400, "train abm/small", "steps", stream=out) as bar:
        for _ in range(1400):
            bar.update(1, loss=0.5)
    lines = out.getvalue().splitlines()
    assert len(lines) == 10 and "\r" not in out.getvalue()
    assert lines[0].startswith("train abm/small: 140/1400 steps (10 %), ") and "left" in lines[0]
    assert lines[-1].startswith("train abm/small: 1400/1400 steps (100 %)") and lines[-1].endswith("loss=0.5")


def test_a_line_per_interval_when_work_is_slow_and_a_final_line() -> None:
    out = io.StringIO()
    bar = Progress(1000, "eval seen", "episodes", initial=10, stream=out, interval_s=0.0)
    bar.update(1)
    bar.update(1)
    bar.close()
    assert [line.split(",")[0] for line in out.getvalue().splitlines()] == [
        "eval seen: 11/1000 episodes (1 %)", "eval seen: 12/1000 episodes (1 %)"]  # close adds nothing new
    done = io.StringIO()
    Progress(0, "eval unseen", "episodes", stream=done).close()  # a resumed evaluation with nothing left
    assert done.getvalue() == ""


def test_a_bar_on_a_terminal_plain_lines_without_bar_nothing_when_disabled() -> None:
    tty = Terminal()
    with Progress(10, "generate", "episodes", stream=tty) as bar:
        bar.update(10)
    assert bar.interactive and "\r" in tty.getvalue()
    tty = Terminal()
    with Progress(10, "generate", "episodes", stream=tty, bar=False) as bar:  # --no-progress
        bar.update(10)
    assert not bar.interactive and tty.getvalue() == "generate: 10/10 episodes (100 %), 0 s\n"
    quiet = io.StringIO()
    with Progress(10, "rank 1", stream=quiet, enabled=False) as bar:
        bar.update(10)
        bar.write("hidden")
    assert quiet.getvalue() == ""


def test_train_logs_summary_validation_loss_plain_lines_and_curve(tmp_path, capsys) -> None:
    """`abm train` in a log: a start-up summary, plain progress lines, the held-out loss at every checkpoint
    (also in log.csv) and the training-curve PNG."""
    from abm.cli import main
    from abm.data.episode_store import save_episode
    from abm.train.synthetic import synthetic_episodes

    for i, episode in enumerate(synthetic_episodes(2, camera_resolution=32, seed=50)):
        save_episode(episode, tmp_path / "val" / f"ep{i}.h5")
    run = tmp_path / "run"
    assert main(["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "4",
                 "--batch", "2", "--checkpoint-every", "2", "--val-data", str(tmp_path / "val"), "--out", str(run),
                 "--set", "resolution=32", "--set", "width=32", "--set", "heads=2", "--set", "layers_within=1",
                 "--set", "layers_joint=1", "--set", "stem_channels=8", "--set", "lang_dim=16"]) == 0
    err = capsys.readouterr().err
    assert "abm train: abm (small+custom, " in err and "parameters, 32² views) on 2 episodes / " in err
    assert "4 steps of batch 2 x 1 process(es), adamw lr 0.001, warm-up 50 (not shorter than the run: the lr never " \
           "reaches its peak), device cpu" in err
    assert "validation: " in err and "held-out keyframes from" in err
    assert "train abm/small: step 2, loss " in err and ", validation loss " in err
    assert "train abm/small: 4/4 steps (100 %)" in err and "\r" not in err
    with (run / "log.csv").open() as f:
        rows = list(csv.DictReader(f))
    held_out = {int(r["step"]): float(r["val_total"]) for r in rows if r["val_total"]}
    assert sorted(held_out) == [2, 4] and all(v > 0 for v in held_out.values())
    assert (run / "training_curve.png").stat().st_size > 1000


def test_the_time_left_leaves_out_the_start_up_and_waits_for_a_rate(monkeypatch) -> None:
    """A 100-unit job whose first unit takes 100 s (imports, a model, a renderer) and every other 1 s: the line at
    10 % says ~1.5 min left (the start-up counted would say ~16 min); before 3 units after the first, no guess."""
    import abm.progress

    clock = [0.0]
    monkeypatch.setattr(abm.progress.time, "monotonic", lambda: clock[0])
    out = io.StringIO()
    bar = Progress(100, "eval seen", "episodes", stream=out, interval_s=1e9)
    clock[0] = 100.0
    bar.update(1)
    for _ in range(9):
        clock[0] += 1.0
        bar.update(1)
    assert out.getvalue().splitlines() == ["eval seen: 10/100 episodes (10 %), 1.8 min, ~1.5 min left"]
    early = io.StringIO()
    slow = Progress(10, "eval unseen", "episodes", stream=early, interval_s=0.0)
    for _ in range(4):
        clock[0] += 30.0
        slow.update(1)
    lines = early.getvalue().splitlines()
    assert [line.rsplit(", ", 1)[-1] for line in lines] == ["estimating time left"] * 3 + ["~3.0 min left"]
