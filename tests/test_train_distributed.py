"""Two-process gloo DDP through torchrun keeps identical parameters on both ranks."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from conftest import TINY_POLICY as TINY


def _torchrun() -> list[str]:
    exe = Path(sys.executable).with_name("torchrun")
    if exe.exists():
        return [str(exe)]
    if shutil.which("torchrun"):
        return ["torchrun"]
    return [sys.executable, "-m", "torch.distributed.run"]


@pytest.mark.slow
def test_torchrun_two_processes_stay_in_sync(tmp_path) -> None:
    out = tmp_path / "run"
    cmd = _torchrun() + ["--standalone", "--nproc_per_node", "2", "-m", "abm.cli", "train", "--method", "abm",
                         "--synthetic", "3", "--camera-resolution", "32", "--steps", "3", "--batch", "1",
                         "--out", str(out), "--no-progress", "--checkpoint-every", "2", "--lr", "0.01"]
    for key, value in TINY.items():
        cmd += ["--set", f"{key}={value}"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world_size"] == 2
    assert len(summary["parameter_digests"]) == 2 and summary["ranks_in_sync"]
    # the parameters actually changed from their initial values
    ckpt = torch.load(out / "checkpoints/step_00000003.pt", weights_only=False)
    assert ckpt["step"] == 3 and ckpt["world_size"] == 2
    first = torch.load(out / "checkpoints/step_00000002.pt", weights_only=False)
    assert any(not torch.equal(first["model"][k], v) for k, v in ckpt["model"].items())
