"""scripts/bootstrap.sh chooses torch's wheel index by the machine and says so in its --dry-run plan."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "bootstrap.sh"


def _dry_run(tmp_path: Path, *, gpu: bool, index: str | None) -> subprocess.CompletedProcess[str]:
    """Run the plan with a venv that does not exist yet, and a fake ``nvidia-smi`` listing a GPU if ``gpu``."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    if gpu:
        fake = bin_dir / "nvidia-smi"
        fake.write_text("#!/bin/sh\necho 'GPU 0: Fake GPU (UUID: GPU-0)'\n")
        fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    env = {**os.environ, "ABM_VENV": str(tmp_path / "venv"), "PATH": f"{bin_dir}:{os.environ['PATH']}"}
    env.pop("ABM_TORCH_INDEX", None)
    if index is not None:
        env["ABM_TORCH_INDEX"] = index
    return subprocess.run(
        ["bash", str(SCRIPT), "--dry-run"], capture_output=True, text=True, env=env, timeout=120, check=False
    )


def test_a_machine_with_a_gpu_takes_the_default_index_and_nothing_is_created(tmp_path: Path) -> None:
    done = _dry_run(tmp_path, gpu=True, index=None)
    assert done.returncode == 0, done.stderr
    assert "torch==2.13.0 from the default index (automatic: NVIDIA GPU yes)" in done.stdout
    assert not (tmp_path / "venv").exists()


def test_an_unreachable_index_falls_back_to_the_default_one(tmp_path: Path) -> None:
    # port 9 (discard) on loopback: nothing listens, the connection is refused at once
    done = _dry_run(tmp_path, gpu=True, index="http://127.0.0.1:9/simple")
    assert done.returncode == 0, done.stderr
    assert "from the default index: http://127.0.0.1:9/simple cannot be reached (ABM_TORCH_INDEX=" in done.stdout


@pytest.mark.parametrize("value", ["gpu", "cu126", "--index-url"])
def test_an_unknown_index_choice_is_refused(tmp_path: Path, value: str) -> None:
    done = _dry_run(tmp_path, gpu=False, index=value)
    assert done.returncode == 2
    assert f"ABM_TORCH_INDEX='{value}' is not cpu, pypi, cuda or an index URL" in done.stderr
