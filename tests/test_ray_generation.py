"""``--backend ray`` of ``abm data generate``: a killed generation resumes, and the same seeds give the same
episodes as the local pool, frame for frame. One local Ray with 2 CPUs is started for the module (skipped where
Ray is not installed); the evaluation and the address checks are in test_ray_eval.py."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator("h5py")
pytest.importorskip("ray")

from abm.cli import main  # noqa: E402
from abm.data.episode_store import find_episode_files, load_episode  # noqa: E402
from ray_helpers import generate_words, local_ray  # noqa: E402

cluster = pytest.fixture(scope="module")(local_ray)  #: one local Ray for the module's tests


def _same_episodes(a_dir, b_dir):
    a_files, b_files = find_episode_files(a_dir), find_episode_files(b_dir)
    assert [f.relative_to(a_dir) for f in a_files] == [f.relative_to(b_dir) for f in b_files] and a_files
    for fa, fb in zip(a_files, b_files, strict=True):
        ea, eb = load_episode(fa), load_episode(fb)
        assert (ea.seed, ea.instruction, len(ea.steps)) == (eb.seed, eb.instruction, len(eb.steps))
        for (oa, aa), (ob, ab) in zip(ea.steps, eb.steps, strict=True):
            assert np.array_equal(aa.position, ab.position) and np.array_equal(aa.quaternion, ab.quaternion)
            assert np.array_equal(oa.cameras["front"].rgb, ob.cameras["front"].rgb)
            assert np.array_equal(oa.gripper_pose, ob.gripper_pose)


def test_killed_ray_generation_resumes_and_equals_the_local_pool(cluster, tmp_path):
    """A driver joined to the cluster by address is killed once an episode is written (its two workers may both
    have finished one: three are asked for, so the set is never complete); the rerun completes the set (each
    seed once) and the episodes equal the local pool's, frame for frame."""
    out = tmp_path / "ray"
    cmd = [sys.executable, "-m", "abm.cli", *generate_words(out, "ray", episodes=3, extra=["--ray-address", cluster])]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600  # generous: Ray's start-up on a loaded 2-core machine took minutes
    while time.time() < deadline and proc.poll() is None and not (out.is_dir() and find_episode_files(out)):
        time.sleep(0.1)
    assert proc.poll() is None, "finished before it could be killed"
    assert out.is_dir() and find_episode_files(out), "no episode was written within the deadline"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert 1 <= len(find_episode_files(out)) < 3
    assert main(generate_words(out, "ray", episodes=3, extra=["--ray-address", cluster])) == 0
    assert [f.name for f in find_episode_files(out)] == [f"episode_{s:06d}.h5" for s in range(3)]
    assert not list(out.rglob(".*tmp*"))
    assert main(generate_words(tmp_path / "local", "local", episodes=3)) == 0
    _same_episodes(out, tmp_path / "local")


