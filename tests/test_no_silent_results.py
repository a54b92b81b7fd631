"""No silent wrong results: training verifies the episodes' checksums, generation re-creates episodes that
fail verification, and ``--resume`` refuses changed hyper-parameters unless told to accept them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from abm.cli import main as cli_main
from abm.data.episode_store import VERIFIED_RECORD, check_episodes, read_info, save_episode, verify_episode
from abm.train.synthetic import synthetic_episodes


@pytest.fixture
def train_args(tiny_sets):
    def args(out: Path, *extra: str) -> list[str]:
        return ["train", "--method", "abm", "--steps", "2", "--batch", "2", "--optimizer", "adamw", "--no-progress",
                "--out", str(out), *tiny_sets, *extra]

    return args


def _damage(path: Path) -> None:
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle: middle + 4096] = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))


def test_training_refuses_episodes_that_fail_their_checksums(tmp_path, capsys, train_args, cli_errors) -> None:
    data = tmp_path / "data"
    for i, ep in enumerate(synthetic_episodes(2, 40)):
        save_episode(ep, data / f"ep{i}.h5")
    assert check_episodes(sorted(data.glob("*.h5")), data) == []
    record = json.loads((data / VERIFIED_RECORD).read_text())
    assert sorted(record) == ["ep0.h5", "ep1.h5"]  # verified once: later checks only compare size and time
    _damage(data / "ep1.h5")
    args = train_args(tmp_path / "run", "--data", str(data))
    assert cli_main(args) == 2
    errors = cli_errors()
    assert len(errors) == 1 and "1 episode file(s) in" in errors[0] and "ep1.h5" in errors[0]
    assert "--no-verify" in errors[0] and not (tmp_path / "run").exists()  # refused before anything is written
    # the explicit flag trains on the files as they are (the damaged bytes may or may not be read)
    rc = cli_main([*args, "--no-verify"])
    assert rc in (0, 2) and "fail verification" not in capsys.readouterr().err


def test_generation_recreates_a_truncated_episode(tmp_path, capsys) -> None:
    base = ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--resolution", "32",
            "--workers", "1", "--out", str(tmp_path)]
    assert cli_main(base) == 0
    (path,) = sorted((tmp_path / "pick_block/seen").glob("*.h5"))
    good = path.read_bytes()
    path.write_bytes(good[: len(good) // 2])
    assert cli_main(base) == 0
    out = capsys.readouterr().out.splitlines()[-1]
    assert "1 new, 0 already present" in out
    assert verify_episode(path) and read_info(path).seed == 0  # the same seed, regenerated


def test_resume_refuses_changed_hyper_parameters_unless_accepted(tmp_path, capsys, train_args, cli_errors) -> None:
    run = tmp_path / "run"
    assert cli_main(train_args(run, "--synthetic", "2", "--camera-resolution", "32", "--lr", "0.001")) == 0
    more = train_args(run, "--synthetic", "2", "--camera-resolution", "32", "--resume", "--steps", "4")
    assert cli_main([*more, "--lr", "0.01", "--seed", "3"]) == 2
    errors = cli_errors()
    assert len(errors) == 1 and "trained with other settings (--lr 0.001 -> 0.01, --seed 0 -> 3)" in errors[0]
    assert "--accept-changed-config" in errors[0]
    assert json.loads((run / "config.json").read_text())["train"]["lr"] == 0.001  # left as it was
    assert cli_main([*more, "--lr", "0.01", "--seed", "3", "--optimizer", "lamb"]) == 2
    assert "cannot continue under another optimizer" in cli_errors()[0]
    # accepted: the new rate is the one the optimiser uses, and config.json says what changed
    assert cli_main([*more, "--lr", "0.01", "--seed", "3", "--accept-changed-config"]) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["lr"] == 0.01 and config["changed_on_resume"]["lr"] == [0.001, 0.01]
    ckpt = torch.load(run / "checkpoints/step_00000004.pt", weights_only=True)
    assert ckpt["scheduler"]["base_lrs"] == [0.01] and ckpt["optimizer"]["param_groups"][0]["initial_lr"] == 0.01
    # the same settings resume without a word; --steps may grow
    assert cli_main([*train_args(run, "--synthetic", "2", "--camera-resolution", "32", "--resume", "--steps", "5"),
                     "--lr", "0.01", "--seed", "3"]) == 0


@pytest.mark.parametrize("flag", ["--no-verify", "--accept-changed-config"])
def test_the_flags_are_documented(flag, capsys) -> None:
    with pytest.raises(SystemExit):
        cli_main(["train", "--help"])
    assert flag in capsys.readouterr().out
