"""Fixtures shared by the test modules.

* ``tiny_policy`` / ``tiny_sets``: the tiny policy sizes the training, evaluation and robot tests use
  (a fresh dict per test, and the same as ``--set=key=value`` command-line words).
* ``shared_tiny_run`` / ``tiny_run``: a trained tiny ``abm`` run folder (2 synthetic episodes, 2 steps),
  trained once per session; ``tiny_run`` is a fresh copy for the test, so a test may write
  into it (and kill a command working on it).
* ``expert_episode``: ``expert_episode(task, split, seed, resolution)`` rolls out the scripted expert
  once per session and arguments (and ``expert_episode.final_tcp_pose(...)`` is where the gripper ended);
  the episode is shared, so tests must only read it.
* ``TINY_POLICY`` (a constant, ``from conftest import TINY_POLICY`` where module-level helpers need it).
* ``cli_errors``: the ``abm: error:`` lines a command printed (and no traceback).
* every test leaves ``LP_NUM_THREADS`` as it found it (an in-process ``run_job`` sets it:
  ``abm.sim.cameras.single_threaded_rasterizer``).
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

# No command resolves its default grounder to the checkout's benchmark CLIP (models/benchmark-clip) in the tests:
# the commands that name no grounder fall to the oracle, as on a machine without CLIP weights
# (abm.grounding.default; the tests of that order set their own).
os.environ.setdefault("ABM_BENCHMARK_CLIP", str(Path(tempfile.gettempdir()) / "abm-tests-no-benchmark-clip"))
# The expert keyframes' disk cache (abm.evaluation.expert_cache) of the tests is their own, so a run computes them
# with the code under test and leaves the user's cache alone.
if "ABM_EXPERT_CACHE" not in os.environ:
    os.environ["ABM_EXPERT_CACHE"] = tempfile.mkdtemp(prefix="abm-tests-expert-keyframes-")
    atexit.register(shutil.rmtree, os.environ["ABM_EXPERT_CACHE"], True)  # not left in the temporary folder

REPO_MODELS = Path(__file__).resolve().parents[1] / "models"
_MODELS_BEFORE = pytest.StashKey[dict[str, tuple[int, int]]]()  # models/ at the session's start


def _committed_models() -> dict[str, tuple[int, int]]:
    """``{path: (size, mtime_ns)}`` of every file under the checkout's models/ (the zoo, its CLIP, the carry)."""
    return {str(p.relative_to(REPO_MODELS)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(REPO_MODELS.rglob("*")) if p.is_file() and not p.is_symlink()}


def pytest_sessionstart(session: pytest.Session) -> None:
    session.config.stash[_MODELS_BEFORE] = _committed_models()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Fail the run when a test wrote into the checkout's models/: a scratch root that links the zoo's files and a
    test that writes a stand-in through such a link replace the committed weights (it happened, and a commit took
    the 8-byte stand-ins for the models)."""
    before = session.config.stash.get(_MODELS_BEFORE, None)
    if before is None or hasattr(session.config, "workerinput"):  # the controller checks, once
        return
    after = _committed_models()
    changed = sorted(name for name in before.keys() | after.keys() if before.get(name) != after.get(name))
    if changed:
        session.config.get_terminal_writer().line(
            f"the tests changed files of the checkout's models/: {', '.join(changed[:10])} (restore them with git "
            "checkout; a test must write into its own folder, never through a link to the checkout)", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


TINY_POLICY = {"resolution": 32, "width": 32, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 8,
               "decoder_channels": 4, "lang_dim": 16}


@pytest.fixture(autouse=True)
def _rasterizer_threads_restored() -> Iterator[None]:
    before = os.environ.get("LP_NUM_THREADS")
    yield
    if before is None:
        os.environ.pop("LP_NUM_THREADS", None)
    else:
        os.environ["LP_NUM_THREADS"] = before


@pytest.fixture
def tiny_policy() -> dict[str, int]:
    """Policy size overrides of a tiny, fast model (``PolicyConfig.from_preset('small', ..., **tiny)``)."""
    return dict(TINY_POLICY)


@pytest.fixture
def tiny_sets() -> list[str]:
    """``tiny_policy`` as ``abm train`` words: ``["--set=resolution=32", ...]``."""
    return [f"--set={k}={v}" for k, v in TINY_POLICY.items()]


@pytest.fixture(scope="session")
def shared_tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's trained tiny ``abm`` run folder (shared: tests that write into it use ``tiny_run``)."""
    from abm.cli import main

    out = tmp_path_factory.mktemp("tiny_run") / "run"
    args = ["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "2", "--batch",
            "2", "--lr", "3e-3", "--warmup", "1", "--out", str(out), "--no-progress",
            *[f"--set={k}={v}" for k, v in TINY_POLICY.items()]]
    assert main(args) == 0
    return out


@pytest.fixture
def tiny_run(shared_tiny_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A trained tiny ``abm`` run folder of this test's own (a copy of the session's one, outside
    ``tmp_path`` so the test's folder stays empty)."""
    run = tmp_path_factory.mktemp("tiny_run") / "run"
    shutil.copytree(shared_tiny_run, run)
    return run


class ExpertEpisodes:
    """``expert(task, split, seed, resolution)``: the scripted expert's episode (cameras recorded at
    ``resolution``), rolled out once per session and arguments; ``expert.final_tcp_pose(...)`` (same
    arguments): the gripper's 4x4 pose when that rollout ended.

    Building a scene costs about as much as the expert's rollout, so ``keep_env=True`` keeps the rollout's
    environment open for :meth:`replay_env`, which hands it over (reset to the first state) instead of
    building the scene again.
    """

    def __init__(self) -> None:
        self._episodes: dict[tuple[str, str, int, int], Any] = {}
        self._final: dict[tuple[str, str, int, int], Any] = {}
        self._envs: dict[tuple[str, str, int, int], Any] = {}

    def _rollout(self, task: str, split: str, seed: int, resolution: int, keep_env: bool) -> tuple[str, str, int, int]:
        key = (task, split, int(seed), int(resolution))
        if key not in self._episodes:
            from abm.sim.env import TaskEnv, run_expert

            env = TaskEnv(task, split, int(seed), resolution=int(resolution))
            try:
                self._episodes[key] = run_expert(env)
                self._final[key] = env._require_sim().robot.tcp_pose().copy()
            finally:
                if keep_env:
                    self._envs[key] = env
                else:
                    env.close()
        return key

    def __call__(self, task: str, split: str, seed: int, resolution: int, keep_env: bool = False) -> Any:
        return self._episodes[self._rollout(task, split, seed, resolution, keep_env)]

    def final_tcp_pose(self, task: str, split: str, seed: int, resolution: int) -> Any:
        return self._final[self._rollout(task, split, seed, resolution, False)]

    def replay_env(self, task: str, split: str, seed: int, resolution: int) -> Any:
        """A fresh-state environment of that scene for the caller to use and close: the rollout's own one
        when it was kept, else a new one."""
        from abm.sim.env import TaskEnv

        key = self._rollout(task, split, seed, resolution, True)
        env = self._envs.pop(key, None) or TaskEnv(task, split, int(seed), resolution=int(resolution))
        env.reset()
        return env

    def close(self) -> None:
        while self._envs:
            self._envs.popitem()[1].close()


@pytest.fixture(scope="session")
def expert_episode() -> Iterator[ExpertEpisodes]:
    """The session's expert rollouts (:class:`ExpertEpisodes`; shared: read them, do not change them)."""
    episodes = ExpertEpisodes()
    yield episodes
    episodes.close()


@pytest.fixture
def cli_errors(capsys: pytest.CaptureFixture[str]) -> Callable[[], list[str]]:
    """Call to read the captured stderr so far: its ``abm: error:`` lines (asserting there is no traceback)."""

    def errors() -> list[str]:
        err = capsys.readouterr().err
        assert "Traceback" not in err
        return [line for line in err.splitlines() if line.startswith("abm: error: ")]

    return errors
