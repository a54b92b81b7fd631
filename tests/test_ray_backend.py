"""``--backend ray``: the same seeds give the same episodes and the same results JSON as the local pool,
a killed run resumes, and an address that does not answer is a clear error. One local Ray with 2 CPUs
is started for the module (skipped where Ray is not installed)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator("h5py")
ray = pytest.importorskip("ray")

from abm.cli import main  # noqa: E402
from abm.data.episode_store import find_episode_files, load_episode  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, object_store_memory=150 * 1024**2)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


def _gen(out, backend, episodes=2, extra=()):
    return ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", str(episodes),
            "--workers", "2", "--resolution", "16", "--out", str(out), "--backend", backend, *extra]


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
    cmd = [sys.executable, "-m", "abm.cli", *_gen(out, "ray", episodes=3, extra=["--ray-address", cluster])]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600  # generous: Ray's start-up on a loaded 2-core machine took minutes
    while time.time() < deadline and proc.poll() is None and not (out.is_dir() and find_episode_files(out)):
        time.sleep(0.1)
    assert proc.poll() is None, "finished before it could be killed"
    assert out.is_dir() and find_episode_files(out), "no episode was written within the deadline"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert 1 <= len(find_episode_files(out)) < 3
    assert main(_gen(out, "ray", episodes=3, extra=["--ray-address", cluster])) == 0
    assert [f.name for f in find_episode_files(out)] == [f"episode_{s:06d}.h5" for s in range(3)]
    assert not list(out.rglob(".*tmp*"))
    assert main(_gen(tmp_path / "local", "local", episodes=3)) == 0
    _same_episodes(out, tmp_path / "local")


def test_eval_on_ray_gives_the_same_results_json(cluster, tiny_run, tmp_path):
    run = tiny_run  # a trained tiny abm run
    results, rollouts = {}, {}
    for backend in ("ray", "local"):
        out = tmp_path / f"eval_{backend}"
        assert main(["eval", "--run", str(run), "--tasks", "pick_block", "--split", "seen", "--episodes", "2",
                     "--repeats", "1", "--max-steps", "2", "--resolution", "32", "--workers", "2",
                     "--backend", backend, "--out", str(out)]) == 0
        results[backend] = json.loads((out / "results.json").read_text())
        outcomes = [json.loads(line) for line in (out / "outcomes.jsonl").read_text().splitlines()]
        assert sorted(o["episode"] for o in outcomes) == [0, 1] and not any(o["error"] for o in outcomes)
        # episode by episode, down to the digest of the keyframes predicted
        rollouts[backend] = {o["episode"]: (o["success"], o["steps"], o["failure"], o["trajectory"]) for o in outcomes}
    assert results["ray"] == results["local"]
    assert rollouts["ray"] == rollouts["local"] and all(r[3] for r in rollouts["local"].values())


def test_a_ray_address_that_does_not_answer_is_a_clear_error(tmp_path, capsys):
    assert main(_gen(tmp_path / "d", "ray", extra=["--ray-address", "127.0.0.1:9"])) == 2
    assert "does not answer" in capsys.readouterr().err
    assert main(_gen(tmp_path / "d", "ray", extra=["--ray-address", "nonsense"])) == 2
    assert "host:port" in capsys.readouterr().err


def test_an_address_that_accepts_but_never_answers_fails_within_30_s_in_one_line(tmp_path):
    """A port that accepts TCP connections but never speaks (not a Ray head, or a hung one): one line, well within
    30 s, and none of Ray's own log lines (Ray itself retries for minutes)."""
    import socket
    import threading

    held = []
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]

        def accept() -> None:
            while True:
                try:
                    held.append(server.accept()[0])  # keep it open, say nothing
                except OSError:
                    return

        threading.Thread(target=accept, daemon=True).start()
        src = os.path.dirname(os.path.dirname(os.path.abspath(__import__("abm").__file__)))
        start = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "abm.cli", *_gen(tmp_path / "d", "ray",
                                                                      extra=["--ray-address", f"127.0.0.1:{port}"])],
                              capture_output=True, text=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": src})
        elapsed = time.monotonic() - start
    for conn in held:
        conn.close()
    assert held, "the command never connected"
    assert done.returncode == 2 and elapsed < 30, (done.returncode, elapsed, done.stderr)
    assert done.stderr.splitlines() == [
        f"abm: error: --ray-address 127.0.0.1:{port}: something accepts connections there but did not answer the Ray "
        "(gRPC) handshake within 10 s, so it is not a Ray head (or it hangs); give the head's GCS address "
        "(`ray status` on the head prints it, port 6379 by default) or ray://host:10001"]
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("words", [
    ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--out", "d"],
    ["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--out", "d", "--backend",
     "local"],
    ["eval", "--run", "r", "--tasks", "pick_block"],
    ["experiment", "run", "quickstart"],
])
def test_a_ray_address_without_the_ray_backend_is_refused(words, capsys):
    """Given without --backend ray, --ray-address was silently ignored (the work ran locally)."""
    with pytest.raises(SystemExit) as exit_info:
        main([*words, "--ray-address", "10.0.0.1:6379"])
    err = capsys.readouterr().err
    command = " ".join(w for w in words[:2] if not w.startswith("-") and w not in ("d", "r", "quickstart"))
    assert exit_info.value.code == 2 and err.splitlines() == [
        "abm: error: --ray-address 10.0.0.1:6379 is only used with --backend ray (this command runs --backend local, "
        f"which would ignore it): add --backend ray, or leave --ray-address out (see abm {command} --help)"]
