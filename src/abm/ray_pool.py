"""Ray backend of ``abm data generate``, ``abm eval`` and ``abm experiment run`` (``--backend ray``;
``pip install 'abm[ray]'``).

:class:`RayActorPool` is a drop-in for :class:`concurrent.futures.ProcessPoolExecutor` as the two commands
use it (``submit`` returning a :class:`concurrent.futures.Future`, a context manager): ``workers`` Ray
actors, each a long-lived process that runs one job at a time and keeps what it loaded (its simulator
scenes, the evaluated policies) between jobs. Jobs are the same functions with the same seeds as in the
local pool, so results do not depend on the backend; resume works the same (the driver writes every
result to disk as it arrives).

Ray is joined at ``address`` (a running cluster: ``host:port`` of the head, ``ray://host:10001`` or
``auto``), or started locally with ``workers`` CPUs. Every node needs abm installed (and the simulation
assets); actors inherit the driver's ``MUJOCO_GL``.
"""

from __future__ import annotations

import argparse
import os
import socket
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from abm.errors import ExternalError

CONNECT_TIMEOUT_S = 5.0
#: how long the Ray head may take to answer the start of the gRPC (HTTP/2) handshake that every Ray connection
#: begins with; a gRPC server answers at once, before any request
HANDSHAKE_TIMEOUT_S = 10.0
#: an HTTP/2 client's connection preface and an empty SETTINGS frame (RFC 9113, 3.4 and 6.5)
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_SETTINGS_FRAME = 4


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--backend local|ray`` and ``--ray-address`` (abm data generate, abm eval, abm experiment run).

    A parser with a ``post_parse_checks`` list (abm's :class:`abm.cli.Parser`) also refuses ``--ray-address``
    without ``--backend ray`` (:func:`backend_arguments_problem`) when the command line is parsed."""
    parser.add_argument("--backend", default="local", choices=["local", "ray"],
                        help="where the --workers run: local processes (default) or Ray actors, each owning its "
                             "simulator (pip install 'abm[ray]')")
    parser.add_argument("--ray-address", default=None,
                        help="Ray cluster to join with --backend ray (host:port of the head, ray://host:10001, or "
                             "auto); default: start a local Ray with --workers CPUs")
    checks = getattr(parser, "post_parse_checks", None)
    if isinstance(checks, list):
        checks.append(backend_arguments_problem)


def backend_arguments_problem(args: argparse.Namespace) -> str | None:
    """Why the parsed ``--backend`` / ``--ray-address`` do not go together (``None`` when they do): an address
    is only used by ``--backend ray``, so without it the address would be silently ignored."""
    address = getattr(args, "ray_address", None)
    backend = getattr(args, "backend", "local")
    if address is not None and backend != "ray":
        return (f"--ray-address {address} is only used with --backend ray (this command runs --backend {backend}, "
                "which would ignore it): add --backend ray, or leave --ray-address out")
    return None


class RayBackendError(ExternalError):
    """Ray is not installed, or the cluster address does not answer."""


def _check_address(address: str) -> None:
    """Fail fast (instead of Ray's long retries) when ``host:port`` does not accept connections."""
    if address in ("auto", "local"):
        return
    target = address.split("://", 1)[-1].rstrip("/")
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise RayBackendError(f"--ray-address {address!r}: give host:port of the Ray head (e.g. 10.0.0.1:6379), "
                              "ray://host:10001, or auto")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S) as conn:
            answer = _http2_answer(conn)
    except OSError as err:
        raise RayBackendError(f"--ray-address {address}: the Ray head does not answer ({err}); start it with "
                              "`ray start --head` on that machine or check the address") from None
    if answer is None:
        raise RayBackendError(f"--ray-address {address}: something accepts connections there but did not answer the "
                              f"Ray (gRPC) handshake within {HANDSHAKE_TIMEOUT_S:g} s, so it is not a Ray head (or it "
                              "hangs); give the head's GCS address (`ray status` on the head prints it, port 6379 by "
                              "default) or ray://host:10001")
    if not answer:
        raise RayBackendError(f"--ray-address {address}: the program listening there does not speak Ray's protocol "
                              "(gRPC); give the head's GCS address (`ray status` on the head prints it, port 6379 by "
                              "default) or ray://host:10001")


def _http2_answer(conn: socket.socket) -> bool | None:
    """Send the start of an HTTP/2 connection (what gRPC, and so every Ray connection, begins with) and wait for
    the server's SETTINGS frame: ``True`` when it came, ``False`` for another answer or a closed connection,
    ``None`` when nothing came within :data:`HANDSHAKE_TIMEOUT_S`."""
    conn.settimeout(HANDSHAKE_TIMEOUT_S)
    try:
        conn.sendall(_HTTP2_PREFACE)
        header = b""
        while len(header) < 9:
            block = conn.recv(9 - len(header))
            if not block:
                return False
            header += block
    except TimeoutError:
        return None
    return header[3] == _SETTINGS_FRAME


def init_ray(address: str | None, num_cpus: int) -> Any:
    """Import Ray and connect (``address``) or start a local instance; returns the ``ray`` module."""
    try:
        import ray
    except ImportError:
        raise RayBackendError("--backend ray needs Ray: pip install 'abm[ray]'") from None
    if address:
        _check_address(address)
    if ray.is_initialized():
        return ray
    env = {k: os.environ[k] for k in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "PYTHONPATH") if k in os.environ}
    if address:
        try:
            ray.init(address=address, runtime_env={"env_vars": env} if env else None, log_to_driver=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise RayBackendError(f"--ray-address {address}: cannot join the Ray cluster ({err})") from None
    else:
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    return ray


def _single_thread() -> None:
    import torch

    torch.set_num_threads(1)


class _Worker:
    """One actor: runs jobs one at a time in its own process (state such as loaded policies persists)."""

    def __init__(self, initializer: Callable[[], None] | None) -> None:
        if initializer is not None:
            initializer()

    def run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return fn(*args)


class RayActorPool:
    """``workers`` Ray actors behind a ``submit(fn, *args) -> Future`` interface.

    Args:
        workers: number of actors (each asks Ray for one CPU).
        address: Ray cluster address; ``None`` starts a local Ray with ``workers`` CPUs.
        initializer: called once in every actor before its first job (default: torch to one thread, as the
            local evaluation pool does).
        cpus_per_worker: CPUs Ray reserves for each actor (a job that runs a multi-threaded command, such as
            one training of ``abm experiment run --backend ray``, asks for its threads).
    """

    def __init__(self, workers: int, address: str | None = None,
                 initializer: Callable[[], None] | None = _single_thread, cpus_per_worker: int = 1) -> None:
        ray = init_ray(address, max(1, workers) * cpus_per_worker)
        actor = ray.remote(num_cpus=cpus_per_worker, max_restarts=0)(_Worker)
        self._actors = [actor.remote(initializer) for _ in range(max(1, workers))]
        self._idle = deque(self._actors)
        self._queue: deque[tuple[Future[Any], Callable[..., Any], tuple[Any, ...]]] = deque()
        self._lock = threading.Lock()
        self._ray = ray

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        fut: Future[Any] = Future()
        with self._lock:
            self._queue.append((fut, fn, args))
        self._dispatch()
        return fut

    def _dispatch(self) -> None:
        while True:
            with self._lock:
                if not self._idle or not self._queue:
                    return
                actor = self._idle.popleft()
                fut, fn, args = self._queue.popleft()
            ref = actor.run.remote(fn, *args)
            ref.future().add_done_callback(lambda done, a=actor, f=fut: self._finished(a, f, done))

    def _finished(self, actor: Any, fut: Future[Any], done: Future[Any]) -> None:
        err = done.exception()
        if err is not None:
            fut.set_exception(err)
        else:
            fut.set_result(done.result())
        with self._lock:
            self._idle.append(actor)
        self._dispatch()

    def shutdown(self, wait: bool = True) -> None:
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []

    def __enter__(self) -> RayActorPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
