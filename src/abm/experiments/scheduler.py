"""Run an experiment's jobs: N at a time × T threads each, as local subprocesses or on a Ray cluster.

Every job is a typed job (:mod:`abm.experiments.jobs`) written to a file and run by its own process,
``python -m abm.experiments.jobs JOB.json`` (:meth:`Source.job`), from a :class:`Source` tree: the checkout whose
``src/`` goes first on ``PYTHONPATH``, so a worktree pinned at a commit trains exactly that code while the
checkout moves on. Its output goes to a log file; the engine reads results from the files the job writes, never
from its output.

Locally (:class:`LocalRunner`) a job starts as soon as a slot frees; the last job left alone gets every
slot's threads. With Ray (:class:`RayRunner`) every job goes through :class:`abm.ray_pool.RayActorPool`: one
actor per slot, each asking Ray for ``threads`` CPUs and running one command at a time on whichever node Ray
placed it (the working folder must be the same shared path on every node). The runners run any command line
(:class:`Command`); the engine's are the job processes.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import abm
from abm import ray_pool
from abm.errors import ConfigError

if TYPE_CHECKING:
    from abm.experiments.jobs import TypedJob

log = logging.getLogger("abm")
POLL_S = 0.5  #: how often the local runner looks at its processes (seconds)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class Source:
    """The code the jobs run.

    Attributes:
        tree: a checkout (holds ``src/abm``); ``None``: the installed package.
    """

    tree: Path | None

    @classmethod
    def here(cls) -> Source:
        """The checkout this process imported abm from, if it is one (``src/abm``), else the installed package."""
        package = Path(abm.__file__).resolve().parent
        return cls(package.parent.parent if package.parent.name == "src" else None)

    @classmethod
    def at(cls, tree: Path) -> Source:
        """The checkout at ``tree`` (refused when it has no ``src/abm``)."""
        if not (tree / "src" / "abm" / "__init__.py").is_file():
            raise ConfigError(f"--source {tree}: not an abm checkout (no src/abm/__init__.py)")
        return cls(tree.resolve())

    @staticmethod
    def job(file: str) -> list[str]:
        """The process of a job written to ``file``: ``python -m abm.experiments.jobs FILE`` with this interpreter
        (:func:`abm.experiments.stages.runs_job` finds a running job by its file on that command line)."""
        return [sys.executable, "-m", "abm.experiments.jobs", file]

    def env(self, threads: int | None = None) -> dict[str, str]:
        """The environment of a job: this tree's ``src`` first on ``PYTHONPATH``, ``threads`` torch threads."""
        env = dict(os.environ)
        if self.tree is not None:
            env["PYTHONPATH"] = os.pathsep.join([str(self.tree / "src"), *filter(None, [env.get("PYTHONPATH")])])
        if threads is not None:
            env.update({k: str(threads) for k in THREAD_VARIABLES})
        env.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # idle OpenMP threads do not spin against the other job
        env.setdefault("MUJOCO_GL", "egl")
        return env


@dataclass
class Command:
    """One job's command line.

    Attributes:
        job: its id (``train/abm_oracle``).
        argv: the command (an engine's job: its process, :meth:`Source.job`).
        log: where its output goes (appended).
        threads: torch threads (``None``: the environment's).
        cwd: its working folder (the experiment's root).
        before: called right before it starts (in the engine's process; on Ray, when it is submitted).
        after: called with the exit code once it ended (in the engine's process).
        work: the typed job the command runs (``None``: another command).
    """

    job: str
    argv: list[str]
    log: Path
    cwd: Path
    threads: int | None = None
    after: Callable[[int], None] | None = field(default=None, repr=False)
    before: Callable[[], None] | None = field(default=None, repr=False)
    work: TypedJob | None = None


class Runner(Protocol):
    """Runs commands ``slots`` at a time; returns each job's exit code."""

    def run(self, commands: Sequence[Command], source: Source, slots: int,
            on_start: Callable[[Command, int | None], None] | None = None) -> dict[str, int]: ...


def _run_blocking(argv: list[str], env: dict[str, str], cwd: str, log: str) -> int:
    """Run one command to its end, output appended to ``log`` (also on a Ray actor: plain arguments only)."""
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as out:
        return subprocess.run(argv, env=env, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, check=False).returncode


class LocalRunner:
    """Local subprocesses, ``slots`` at a time, each with its command's threads (a job started last, with no
    other running or waiting, gets every slot's threads unless ``lend_idle_threads`` is off: another run shares
    the machine). An interrupt stops the running ones (by their ids)."""

    def __init__(self, lend_idle_threads: bool = True) -> None:
        self.lend_idle_threads = lend_idle_threads

    def run(self, commands: Sequence[Command], source: Source, slots: int,
            on_start: Callable[[Command, int | None], None] | None = None) -> dict[str, int]:
        waiting = list(commands)
        running: list[tuple[Command, subprocess.Popen[bytes], Any]] = []
        codes: dict[str, int] = {}
        try:
            while waiting or running:
                while waiting and len(running) < slots:
                    cmd = waiting.pop(0)
                    threads = cmd.threads
                    if threads is not None and self.lend_idle_threads and not waiting and not running:
                        threads *= slots  # alone: the others' threads too
                    if cmd.before is not None:
                        cmd.before()
                    cmd.log.parent.mkdir(parents=True, exist_ok=True)
                    out = cmd.log.open("a")
                    proc = subprocess.Popen(cmd.argv, env=source.env(threads), cwd=cmd.cwd, stdout=out,
                                            stderr=subprocess.STDOUT)
                    running.append((cmd, proc, out))
                    if on_start is not None:
                        on_start(cmd, proc.pid)
                still = []
                for cmd, proc, out in running:
                    code = proc.poll()
                    if code is None:
                        still.append((cmd, proc, out))
                        continue
                    out.close()
                    codes[cmd.job] = code
                    if cmd.after is not None:
                        cmd.after(code)
                running = still
                if running:
                    time.sleep(POLL_S)
        except BaseException:
            for _, proc, _out in running:  # only the processes this runner started
                proc.terminate()
            for _, proc, out in running:
                try:
                    proc.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    proc.kill()
                out.close()
            raise
        return codes


class RayRunner:
    """The commands on Ray actors (:class:`abm.ray_pool.RayActorPool`): ``slots`` actors of ``cpus`` CPUs each,
    at ``address`` (``None``: a local Ray)."""

    def __init__(self, address: str | None, cpus: int = 1) -> None:
        self.address, self.cpus = address, cpus

    def run(self, commands: Sequence[Command], source: Source, slots: int,
            on_start: Callable[[Command, int | None], None] | None = None) -> dict[str, int]:
        codes: dict[str, int] = {}
        with ray_pool.RayActorPool(slots, self.address, initializer=None, cpus_per_worker=self.cpus) as pool:
            futures: list[tuple[Command, Future[int]]] = []
            for cmd in commands:
                if cmd.before is not None:
                    cmd.before()
                if on_start is not None:
                    on_start(cmd, None)
                futures.append((cmd, pool.submit(_run_blocking, cmd.argv, source.env(cmd.threads), str(cmd.cwd),
                                                 str(cmd.log))))
            for cmd, fut in futures:
                code = int(fut.result())
                codes[cmd.job] = code
                if cmd.after is not None:
                    cmd.after(code)
        return codes
