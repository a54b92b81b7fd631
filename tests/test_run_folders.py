"""One writer per run folder, exports that cannot destroy a run, and writes that leave nothing half-done.

The lock is held by a real second process; a full disk is a real write failure (the file-size limit of
this process, ``RLIMIT_FSIZE``, makes the kernel refuse the write like a full disk does).
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

import abm
from abm.cli import main as cli_main
from abm.files import FolderBusyError, FolderLock, WriteError, atomic_path, write_text_atomic
from abm.policy.checkpoint import list_checkpoints, save_checkpoint
from conftest import TINY_POLICY

SRC = str(Path(abm.__file__).parents[1])


def _train_args(out: Path, *extra: str) -> list[str]:
    sets = [f"--set={k}={v}" for k, v in TINY_POLICY.items()]
    return ["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "2", "--batch",
            "2", "--optimizer", "adamw", "--no-progress", "--out", str(out), *sets, *extra]


@pytest.fixture
def run(tiny_run) -> Path:
    return tiny_run


@contextmanager
def _holder(folder: Path, command: str):
    """A second process holding the folder's lock."""
    code = ("import sys, time\nfrom abm.files import FolderLock\n"
            f"lock = FolderLock({str(folder)!r}, {command!r}).__enter__()\nprint('locked', flush=True)\n"
            "time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": SRC})
    try:
        assert proc.stdout.readline().strip() == "locked"
        yield proc
    finally:
        proc.kill()
        proc.wait()


@contextmanager
def _disk_limit(size: int):
    """Writes past ``size`` bytes fail with EFBIG, as a full disk fails them with ENOSPC."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)


def test_a_folder_has_one_writer_and_a_stale_lock_is_taken_over(tmp_path, caplog) -> None:
    folder = tmp_path / "run"
    with _holder(folder, "abm train") as proc:
        with pytest.raises(FolderBusyError, match=rf"run is in use by abm train \(pid {proc.pid} on .*\): one command"):
            FolderLock(folder, "abm eval").__enter__()
    # the holder was killed (-9): its lock file stays, but the lock is stale and is taken over
    assert (folder / ".abm.lock").read_text().startswith("abm train (pid")
    with caplog.at_level("INFO", logger="abm"), FolderLock(folder, "abm eval"):
        assert (folder / ".abm.lock").read_text().startswith(f"abm eval (pid {os.getpid()}")
    assert f"taking over the stale lock of abm train (pid {proc.pid}" in caplog.text
    assert not (folder / ".abm.lock").exists()


def test_train_eval_and_export_refuse_a_folder_in_use(run, tmp_path, capsys, cli_errors) -> None:
    before = [s for s, _ in list_checkpoints(run)]
    with _holder(run, "abm train"):
        assert cli_main(_train_args(run, "--resume", "--steps", "4")) == 2
        errors = cli_errors()
        assert len(errors) == 1 and f"{run} is in use by abm train (pid" in errors[0]
        assert [s for s, _ in list_checkpoints(run)] == before
        assert cli_main(["export", "--run", str(run), "--out", str(run / "policy.pt")]) == 2
        assert "in use by abm train" in cli_errors()[0] and not (run / "policy.pt").exists()
        assert cli_main(["eval", "--run", str(run), "--tasks", "pick_block", "--split", "seen", "--episodes", "1",
                         "--repeats", "1", "--out", str(run)]) == 2
        assert "in use by abm train" in cli_errors()[0] and not (run / "outcomes.jsonl").exists()


def test_export_never_overwrites_a_checkpoint_or_a_file(run, tmp_path, capsys, cli_errors) -> None:
    newest = list_checkpoints(run)[-1][1]
    data = newest.read_bytes()
    cases = {
        str(newest): "is the checkpoint being exported",
        str(run / "checkpoints" / "export.pt"): "is inside a run's checkpoints folder",
        str(run / "checkpoints"): "is a folder; give a file path",
        str(run / "config.json" / "x.pt"): "config.json is a file, not a folder",
    }
    for out, message in cases.items():
        assert cli_main(["export", "--run", str(run), "--out", out]) == 2, out
        errors = cli_errors()
        assert len(errors) == 1 and message in errors[0], errors
    assert newest.read_bytes() == data
    target = tmp_path / "policy.pt"
    assert cli_main(["export", "--run", str(run), "--out", str(target)]) == 0
    first = target.stat().st_mtime_ns
    assert cli_main(["export", "--run", str(run), "--out", str(target)]) == 2
    assert "already exists; pass --overwrite" in cli_errors()[0] and target.stat().st_mtime_ns == first
    assert cli_main(["export", "--run", str(run), "--out", str(target), "--overwrite", "--dtype", "bfloat16"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy.pt"]  # no lock or temporary file left


def test_a_full_disk_leaves_the_old_file_and_no_temporary_file(tmp_path) -> None:
    path = tmp_path / "ckpt.pt"
    save_checkpoint(path, {"step": 1, "blob": b"x" * 100})
    good = path.read_bytes()
    with _disk_limit(64 * 1024), pytest.raises(WriteError, match=r"cannot write .*ckpt.pt: File too large"):
        save_checkpoint(path, {"step": 2, "blob": b"x" * 200_000})
    assert path.read_bytes() == good and sorted(p.name for p in tmp_path.iterdir()) == ["ckpt.pt"]
    with _disk_limit(1024), pytest.raises(WriteError, match="results.json"):
        write_text_atomic(tmp_path / "results.json", "x" * 5000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt.pt"]
    with pytest.raises(WriteError, match="is a file, not a folder"):
        with atomic_path(tmp_path / "ckpt.pt" / "x.json") as tmp:
            tmp.write_text("{}")


def test_a_full_disk_during_training_and_generation_is_one_error_line(tmp_path, capsys, cli_errors) -> None:
    out = tmp_path / "run"
    with _disk_limit(96 * 1024):
        rc = cli_main(_train_args(out))
    errors = cli_errors()
    assert rc == 2 and len(errors) == 1 and "cannot write" in errors[0] and "File too large" in errors[0]
    leftovers = [p.name for p in out.rglob("*") if ".tmp" in p.name or p.name == ".abm.lock"]
    assert leftovers == []

    from abm.data.episode_store import save_episode
    from abm.train.synthetic import synthetic_episodes

    episode = synthetic_episodes(1, 64)[0]
    with _disk_limit(16 * 1024), pytest.raises(WriteError, match="ep.h5: File too large"):
        save_episode(episode, tmp_path / "data" / "ep.h5")
    assert list((tmp_path / "data").iterdir()) == []
