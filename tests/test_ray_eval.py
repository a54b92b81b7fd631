"""``--backend ray`` of ``abm eval`` gives the same results JSON and rollouts as the local pool; an address that
does not answer, or answers without speaking Ray's protocol, is a clear error; ``--ray-address`` without
``--backend ray`` is refused. One local Ray with 2 CPUs is started for the module (skipped where Ray is not
installed); the generation on Ray is in test_ray_generation.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from sim_helpers import require_simulator

require_simulator("h5py")
pytest.importorskip("ray")

from abm.cli import main  # noqa: E402
from ray_helpers import generate_words, local_ray  # noqa: E402

cluster = pytest.fixture(scope="module")(local_ray)  #: one local Ray for the module's tests


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
    assert main(generate_words(tmp_path / "d", "ray", extra=["--ray-address", "127.0.0.1:9"])) == 2
    assert "does not answer" in capsys.readouterr().err
    assert main(generate_words(tmp_path / "d", "ray", extra=["--ray-address", "nonsense"])) == 2
    assert "host:port" in capsys.readouterr().err


def test_an_address_that_accepts_but_never_answers_fails_within_30_s_in_one_line(tmp_path):
    """A port that accepts TCP connections but never speaks (not a Ray head, or a hung one): one line, well within
    30 s, and none of Ray's own log lines (Ray itself retries for minutes). The clock starts at the first connection,
    so a loaded machine's slow start of Python (importing torch and Ray) does not count against the handshake's
    bound."""
    import socket
    import threading

    held = []
    accepted: list[float] = []  # when each connection came, monotonic s
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]

        def accept() -> None:
            while True:
                try:
                    conn = server.accept()[0]
                    accepted.append(time.monotonic())
                    held.append(conn)  # keep it open, say nothing
                except OSError:
                    return

        threading.Thread(target=accept, daemon=True).start()
        src = os.path.dirname(os.path.dirname(os.path.abspath(__import__("abm").__file__)))
        start = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "abm.cli", *generate_words(tmp_path / "d", "ray",
                                                                      extra=["--ray-address", f"127.0.0.1:{port}"])],
                              capture_output=True, text=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": src})
        ended = time.monotonic()
    for conn in held:
        conn.close()
    assert held, "the command never connected"
    elapsed = ended - accepted[0]
    assert done.returncode == 2 and elapsed < 30, (done.returncode, elapsed, ended - start, done.stderr)
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
