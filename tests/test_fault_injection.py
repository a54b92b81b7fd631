"""Fault injection: ``kill -9`` of data generation, training and evaluation at seeded random moments, and a
scheduler's SIGTERM during training, then resume. Nothing is lost or duplicated, the resumed training curve equals
an uninterrupted one, and no worker process outlives its command."""

from __future__ import annotations

import csv
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import TINY_POLICY

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _workers(pid: int) -> list[int]:
    found = []
    for child in _children(pid):
        try:
            cmd = Path(f"/proc/{child}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmd:
            found.append(child)
    return found


def test_kill_9_of_data_generate_leaves_no_workers(tmp_path):
    cmd = [sys.executable, "-m", "abm.cli", "data", "generate", "--task", "pick_block", "--split", "seen",
           "--episodes", "20", "--workers", "2", "--resolution", "16", "--out", str(tmp_path / "d")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.time() + 60
        workers: list[int] = []
        while time.time() < deadline and len(workers) < 2:
            time.sleep(0.2)
            workers = _workers(proc.pid)
        assert len(workers) == 2, "the pool did not start"
        time.sleep(1.0)  # let them get into a simulation
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.time() + 10
        while time.time() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.2)
        assert not any(_alive(w) for w in workers), "workers outlived the killed command"
    finally:
        if proc.poll() is None:
            proc.kill()
    # resuming completes the set: every planned episode exactly once, each one intact
    from abm.data.episode_store import EpisodeStore, verify_episode

    done = subprocess.run(cmd[:cmd.index("--episodes") + 1] + ["4"] + cmd[cmd.index("--episodes") + 2:],
                          capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    store = EpisodeStore(tmp_path / "d")
    assert len(store) >= 4 and len({e.seed for e in store.episodes}) == len(store)
    for info in store.episodes:
        verify_episode(info.path)


ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def _train_cmd(out: Path, steps: int, checkpoint_every: int = 2) -> list[str]:
    cmd = [sys.executable, "-m", "abm.cli", "train", "--method", "abm", "--synthetic", "2", "--camera-resolution",
           "32", "--steps", str(steps), "--batch", "2", "--checkpoint-every", str(checkpoint_every), "--log-every",
           "1", "--lr", "3e-3", "--warmup", "2", "--out", str(out), "--no-progress", "--resume"]
    for key, value in TINY_POLICY.items():
        cmd += ["--set", f"{key}={value}"]
    return cmd


def _log(run: Path) -> dict[int, float]:
    with (run / "log.csv").open() as f:
        rows = list(csv.DictReader(f))
    steps = [int(r["step"]) for r in rows]
    assert len(steps) == len(set(steps)), f"duplicated log rows: {steps}"
    return {int(r["step"]): float(r["total"]) for r in rows}


def _signal_when(proc: subprocess.Popen, ready, sig: signal.Signals, timeout: float = 120) -> None:
    """Send ``sig`` to ``proc`` once ``ready()`` holds (it must still run then)."""
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None and not ready():
        time.sleep(0.05)
    assert proc.poll() is None, "finished before it could be signalled"
    os.kill(proc.pid, sig)


def _kill_when(proc: subprocess.Popen, ready, timeout: float = 120) -> None:
    _signal_when(proc, ready, signal.SIGKILL, timeout)
    proc.wait()


def _reference_curve(run: Path, steps: int, checkpoint_every: int = 2) -> dict[int, float]:
    """The loss curve of an uninterrupted :func:`_train_cmd` run (in this process: one interpreter start-up less)."""
    import torch

    from abm.cli import main

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # like OMP_NUM_THREADS=1 of the commands
    try:
        assert main(_train_cmd(run, steps, checkpoint_every)[3:]) == 0
    finally:
        torch.set_num_threads(threads)
    return _log(run)


def test_kill_9_during_training_then_resume_gives_the_same_curve(tmp_path):
    steps = 60  # long enough (~15 ms a step) that the kill always lands before the last step
    reference = _reference_curve(tmp_path / "ref", steps)
    kill_after = random.Random(0).randint(3, 6)  # a seeded random moment, between checkpoints or not
    run = tmp_path / "run"
    proc = subprocess.Popen(_train_cmd(run, steps), env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log = run / "log.csv"
    _kill_when(proc, lambda: log.is_file() and len(log.read_text().splitlines()) > kill_after)
    resumed = subprocess.run(_train_cmd(run, steps), env=ENV, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    curve = _log(run)
    assert sorted(curve) == list(range(1, steps + 1))
    for step, loss in reference.items():
        assert abs(curve[step] - loss) <= 1e-4 * max(1.0, abs(loss)), (step, curve[step], loss)


def test_sigterm_during_training_saves_the_step_it_reached_then_resume_gives_the_same_curve(tmp_path):
    """A scheduler's SIGTERM (the experiment engine stopping a job): the step in progress ends, a checkpoint of it
    is saved even between periodic checkpoints, the command exits like Ctrl-C, and the resumed curve is exact.

    The run is long (200 steps of ~10 ms) so that the signal, sent once step 3 is logged, always lands before the
    last step: with 8 steps a fast machine finished training between the poll and the signal."""
    steps = 200
    only_sigterms = 10 * steps  # no periodic checkpoint: only SIGTERM's
    reference = _reference_curve(tmp_path / "ref", steps, only_sigterms)
    run = tmp_path / "run"
    cmd = _train_cmd(run, steps, only_sigterms)
    proc = subprocess.Popen(cmd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = run / "log.csv"
    _signal_when(proc, lambda: log.is_file() and len(log.read_text().splitlines()) > 3, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    saved = sorted(int(p.stem.split("_")[1]) for p in (run / "checkpoints").glob("step_*.pt"))
    assert len(saved) == 1 and 3 <= saved[0] < steps, saved
    assert f"checkpoint saved at step {saved[0]}" in err
    assert sorted(_log(run)) == list(range(1, saved[0] + 1))  # the log ends at the saved step
    resumed = subprocess.run(cmd, env=ENV, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    curve = _log(run)
    assert sorted(curve) == list(range(1, steps + 1))
    for step, loss in reference.items():
        assert abs(curve[step] - loss) <= 1e-4 * max(1.0, abs(loss)), (step, curve[step], loss)


def test_kill_9_during_evaluation_then_resume_runs_each_episode_once(tiny_run, tmp_path):
    run = tiny_run  # a trained tiny abm run
    out = tmp_path / "ev"
    cmd = [sys.executable, "-m", "abm.cli", "eval", "--run", str(run), "--tasks", "pick_block", "--split", "seen",
           "--episodes", "4", "--repeats", "1", "--max-steps", "2", "--resolution", "32", "--out", str(out)]
    log = out / "outcomes.jsonl"
    proc = subprocess.Popen(cmd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _kill_when(proc, lambda: log.is_file() and len(log.read_text().splitlines()) >= 1, timeout=240)
    with log.open("a") as f:  # as if killed in the middle of writing a record
        f.write('{"method": "abm", "task": "pick')
    done = subprocess.run(cmd, env=ENV, capture_output=True, text=True, timeout=400)
    assert done.returncode == 0, done.stderr[-2000:]
    records = []
    for line in log.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    keys = [(r["repeat"], r["episode"]) for r in records]
    assert sorted(keys) == [(0, e) for e in range(4)], keys  # each planned episode exactly once
    results = json.loads((out / "results.json").read_text())
    assert results[0]["episodes"] == 4


def test_the_first_sigterm_raises_the_flag_and_a_second_one_acts_as_before():
    """Inside StopOnTerm the first SIGTERM only raises the flag (the loop stops after its step); a second one goes
    to the handler that was there before (by default: the end of the process, for a step that never ends), and
    leaving restores that handler."""
    from abm.train.stop import StopOnTerm

    before: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: before.append(signum))
    try:
        with StopOnTerm() as stop:
            assert not stop.flag
            os.kill(os.getpid(), signal.SIGTERM)
            assert stop.flag and before == []
            os.kill(os.getpid(), signal.SIGTERM)
            assert before == [signal.SIGTERM]
        os.kill(os.getpid(), signal.SIGTERM)
        assert before == [signal.SIGTERM] * 2
    finally:
        signal.signal(signal.SIGTERM, previous)
