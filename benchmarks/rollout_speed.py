"""CPU seconds of an evaluation rollout by stage, for zoo models, optionally side by side with another commit.

Each rollout runs through the evaluation's own code path (:func:`abm.evaluation.runner.run_job`, as a worker of
``abm eval`` / ``abm zoo eval`` runs it: the policy loaded once per process, one torch thread, RNGs seeded from
the scene seed) and is timed in process CPU seconds (``time.process_time``: every thread of the process, also
the software GL rasterizer's), split into stages by wrapping the functions that do the work:

* ``reset``: the episode's scene (sampling, compiling the MuJoCo model, the camera renderer) and its settling;
* ``render``: the simulator's cameras (RGB, depth, segmentation of every camera at every observation);
* ``grounding``: the policy's grounder (``ground``: the oracle's segmentation lookup, CLIP's proposals);
* ``policy``: the rest of ``policy.act`` (fusion, virtual views, the networks, decoding);
* ``physics``: executing keyframes (IK along the path, physics steps, contact checks, the success test);
* ``expert``: the scripted expert run on the scene after the rollout for the per-step records (a commit that has
  them: ``abm.evaluation.runner._expert_of``; once per scene and process, so the first model of a scene pays it:
  the servers run with the expert's disk cache off, ``ABM_EXPERT_CACHE=off``, so no tree reads another run's),
  everything inside it included;
* ``other``: the rest of the rollout (a fresh copy of the policy, the outcome's bookkeeping);
* ``total``: the rollout's process CPU seconds.

One untimed rollout (another seed) warms each process up first, so the numbers are a worker's steady state.

    OMP_NUM_THREADS=1 python benchmarks/rollout_speed.py --models abm_oracle_v2 abm_clip_v2 \
        --task place_food --episodes 3 --max-steps 5

Side by side (``--against REF``): one server process runs from a temporary ``git worktree`` of REF (its library,
this script) and one from this tree; the rollouts alternate between them (REF's episode 0, this tree's
episode 0, REF's episode 1, ...), so both see the same machine. Each episode's outcome (success, steps, failure,
trajectory digest) must be the same in both trees, else the benchmark fails. ``--record FILE`` appends the rows
``{commit, model, grounder, stage, seconds_per_rollout, measured, machine}`` (mean over the episodes, stage
``total`` = CPU seconds per rollout; ``measured``: the run's UTC time, the same for every row of a run, so a
run's columns stay together beside earlier runs of the same commits) to a JSON list::

    OMP_NUM_THREADS=1 python benchmarks/rollout_speed.py --against 65d6cab --record docs/results/rollout_speed.json

A model may name the grounder its rollouts use instead of the one its checkpoint stores: ``abm_clip_v2@tracking``
grounds once per episode with the stored CLIP grounder and then tracks the target's points (``abm eval --grounder
tracking``), a protocol of its own, so its row is its own (grounder ``tracking``) and its outcomes are compared
only with the same model and grounder in the other tree::

    OMP_NUM_THREADS=1 python benchmarks/rollout_speed.py --models abm_clip_v2 abm_clip_v2@tracking --against 65d6cab

``--together`` rolls the models out scene by scene (each episode: every model in turn), as an evaluation of several
models orders them, so every model but the first of a scene takes over its build, its first observation and the
CLIP memories; its rows are marked ``"together": true``.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("reset", "render", "grounding", "policy", "physics", "expert", "other")
ABSORBING = ("expert",)  # stages that keep the time of the stages inside them


class StageClock:
    """Process CPU seconds per stage, each second charged to the innermost stage running (a render inside the
    reset counts as render)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._stack: list[str] = ["other"]
        self._mark = time.process_time()

    def _charge(self) -> None:
        now = time.process_time()
        self.seconds[self._stack[-1]] += now - self._mark
        self._mark = now

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        if any(s in ABSORBING for s in self._stack):
            yield
            return
        self._charge()
        self._stack.append(name)
        try:
            yield
        finally:
            self._charge()
            self._stack.pop()

    def take(self) -> dict[str, float]:
        """The seconds since the last call, per stage (and reset the clock)."""
        self._charge()
        out = dict(self.seconds)
        self.seconds.clear()
        return out


def _timed(clock: StageClock, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with clock.stage(name):
            return fn(*args, **kwargs)

    return wrapper


def instrument(clock: StageClock) -> None:
    """Wrap the functions of each stage (the same names exist in the baseline commit and in this tree)."""
    from abm.grounding import grounders
    from abm.policy.keyframe_policy import KeyframePolicy
    from abm.sim.cameras import CameraRig
    from abm.sim.env import TaskEnv
    from abm.sim.simulation import Simulation

    targets: list[tuple[Any, str, str]] = [
        (TaskEnv, "__init__", "reset"), (TaskEnv, "reset", "reset"), (CameraRig, "__init__", "reset"),
        (Simulation, "observe", "render"), (Simulation, "execute", "physics"), (TaskEnv, "success", "physics"),
        (KeyframePolicy, "act", "policy"), (KeyframePolicy, "explain", "policy"),
    ]
    for cls in vars(grounders).values():
        if isinstance(cls, type) and cls.__module__ == grounders.__name__ and "ground" in vars(cls):
            targets.append((cls, "ground", "grounding"))
    from abm.evaluation import runner

    if hasattr(runner, "_expert_of"):
        targets.append((runner, "_expert_of", "expert"))
    for owner, attr, stage in targets:
        setattr(owner, attr, _timed(clock, stage, getattr(owner, attr)))


def serve(args: argparse.Namespace) -> None:
    """Answer requests ``MODEL EPISODE`` on stdin with one JSON line each: the rollout's stages and outcome."""
    import torch

    from abm.evaluation.policies import load_policy
    from abm.evaluation.results import eval_seed
    from abm.evaluation.runner import EvalJob, run_job
    from abm.evaluation.settings import EvalSettings
    from abm.policy.checkpoint import resolve_checkpoint

    torch.set_num_threads(1)
    clock = StageClock()
    instrument(clock)
    import abm

    print(json.dumps({"ready": True, "abm": abm.__file__}), flush=True)
    for line in sys.stdin:
        model, episode = line.split()
        name, override = split_model(model)
        settings = EvalSettings(max_steps=args.max_steps, grounder=override)
        path = str(resolve_checkpoint(ROOT / "models" / f"{name}.pt").resolve())
        load_policy(path, settings)  # once per process, as the evaluation's driver / worker does
        repeat, ep = (9, 0) if episode == "warmup" else (0, int(episode))
        job = EvalJob(path, model, args.task, args.split, repeat, ep, eval_seed(repeat, ep), checkpoint=path,
                      settings=settings.signature())
        clock.take()
        start = time.process_time()
        outcome = run_job(job, settings)
        total = time.process_time() - start
        stages = clock.take()
        print(json.dumps({"model": model, "episode": episode, "total": total, "stages": stages,
                          "outcome": [outcome.success, outcome.steps, outcome.failure, outcome.trajectory],
                          "error": outcome.error}), flush=True)


def _commit(ref: str = "HEAD") -> str:
    out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", ref], capture_output=True, text=True,
                         check=True)
    dirty = ref == "HEAD" and subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "src"],
                                             capture_output=True, text=True).stdout.strip()
    return out.stdout.strip() + ("+" if dirty else "")


def _server(src: Path, args: argparse.Namespace) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1",
           "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "ABM_EXPERT_CACHE": "off"}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--serve", "--task", args.task, "--split", args.split,
           "--max-steps", str(args.max_steps)]
    proc = subprocess.Popen(cmd, env=env, cwd=str(ROOT), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    loaded = Path(_read(proc)["abm"]).resolve()
    if not loaded.is_relative_to(src.resolve()):
        raise SystemExit(f"the server for {src} imported abm from {loaded}")
    return proc


def _read(proc: subprocess.Popen[str]) -> dict[str, Any]:
    stdout: IO[str] | None = proc.stdout
    assert stdout is not None
    line = stdout.readline()
    if not line:
        raise SystemExit(f"a benchmark server stopped (exit {proc.wait()})")
    result: dict[str, Any] = json.loads(line)
    return result


def _ask(proc: subprocess.Popen[str], model: str, episode: str) -> dict[str, Any]:
    assert proc.stdin is not None
    proc.stdin.write(f"{model} {episode}\n")
    proc.stdin.flush()
    result = _read(proc)
    if result.get("error"):
        raise SystemExit(f"{model} episode {episode} crashed: {result['error']}")
    return result


def split_model(model: str) -> tuple[str, str | None]:
    """``NAME@GROUNDER`` -> (NAME, GROUNDER); a plain zoo name -> (NAME, None: the checkpoint's own grounder)."""
    name, _, override = model.partition("@")
    return name, override or None


def grounder_of(model: str) -> str:
    """The grounder a model's rollouts use: the ``@GROUNDER`` it names, else the one its entry in
    ``models/index.json`` stores (``clip``, ``oracle``; ``none`` for a model without a grounder)."""
    name, override = split_model(model)
    if override is not None:
        return override
    index = json.loads((ROOT / "models" / "index.json").read_text())
    entry = next((e for e in index if e["name"] == name), None)
    if entry is None:
        raise SystemExit(f"{name!r} is not a model of models/index.json")
    spec = entry.get("grounder_spec") or {}
    return str(spec.get("kind", "none"))


def run(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Roll out every model's episodes in each tree, alternating between trees; return the rows."""
    with tempfile.TemporaryDirectory() as tmp:
        trees: dict[str, Path] = {}
        if args.against:
            tree = Path(tmp) / "baseline"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(tree), args.against],
                           check=True)
            trees[_commit(args.against)] = tree / "src"
        trees[_commit()] = ROOT / "src"
        servers = {}
        try:
            servers = {commit: _server(src, args) for commit, src in trees.items()}
            results: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
            if args.together:  # warm every model up first, then each scene's rollouts one after another
                for model in args.models:
                    for proc in servers.values():
                        _ask(proc, model, "warmup")
                order = [(model, ep) for ep in range(args.episodes) for model in args.models]
            else:
                order = [(model, ep) for model in args.models for ep in ("warmup", *range(args.episodes))]
            for model, ep in order:
                for commit, proc in servers.items():
                    result = _ask(proc, model, str(ep))
                    if ep == "warmup":
                        continue
                    results[commit, model].append(result)
                    print(f"{commit} {model} episode {ep}: {result['total']:.2f} CPU s, outcome "
                          f"{result['outcome']}", file=sys.stderr, flush=True)
        finally:
            for proc in servers.values():
                if proc.stdin is not None:
                    proc.stdin.close()
                proc.wait()
            if args.against:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(Path(tmp) / "baseline")],
                               check=False)
    commits = list(servers)
    for model in args.models:
        outcomes = {c: [r["outcome"] for r in results[c, model]] for c in commits}
        if any(o != outcomes[commits[0]] for o in outcomes.values()):
            raise SystemExit(f"{model}: the outcomes differ between the commits: {outcomes}")
    rows = []
    for commit in commits:
        for model in args.models:
            runs = results[commit, model]
            grounder = grounder_of(model)
            mode = {"together": True} if args.together else {}
            for stage in STAGES:
                seconds = sum(r["stages"].get(stage, 0.0) for r in runs) / len(runs)
                rows.append({"commit": commit, "model": model, "grounder": grounder, "stage": stage,
                             "seconds_per_rollout": round(seconds, 3), **mode})
            rows.append({"commit": commit, "model": model, "grounder": grounder, "stage": "total",
                         "seconds_per_rollout": round(sum(r["total"] for r in runs) / len(runs), 3), **mode})
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    """A table: one row per stage, one column per (commit, grounder), or per (commit, model) when two models
    share a grounder."""
    key = "grounder" if len({r["grounder"] for r in rows}) == len({r["model"] for r in rows}) else "model"
    columns = list(dict.fromkeys((r["commit"], r[key]) for r in rows))
    value = {(r["commit"], r[key], r["stage"]): r["seconds_per_rollout"] for r in rows}
    lines = ["| stage | " + " | ".join(f"{g} @ {c}" for c, g in columns) + " |",
             "|---|" + "---:|" * len(columns)]
    for stage in (*STAGES, "total"):
        lines.append(f"| {stage} | " + " | ".join(f"{value.get((c, g, stage), 0.0):.2f}" for c, g in columns) + " |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--models", nargs="+", default=["abm_oracle_v2", "abm_clip_v2"],
                   help="zoo model names; NAME@GROUNDER rolls NAME out with another grounder (clip, oracle, tracking)")
    p.add_argument("--task", default="place_food")
    p.add_argument("--split", default="seen")
    p.add_argument("--episodes", type=int, default=3, help="timed rollouts per model (episodes 0..N-1, repeat 0)")
    p.add_argument("--max-steps", type=int, default=5, help="keyframes per rollout at most")
    p.add_argument("--against", default=None, metavar="REF", help="also run from a git worktree of REF, alternating")
    p.add_argument("--together", action="store_true", help="roll out scene by scene (each episode: every model "
                   "in turn), as an evaluation of several models does, so the second model of a scene takes over "
                   "its build, first observation and CLIP memories (rows marked together)")
    p.add_argument("--record", type=Path, default=None, metavar="FILE", help="append the rows to this JSON list, "
                   "each with the run's UTC time and machine")
    p.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.serve:
        serve(args)
        return
    from abm.grounding.config import GROUNDERS

    for model in args.models:  # fail before any server starts (grounder_of: a name the zoo index lacks)
        grounder = grounder_of(model)
        if "@" in model and grounder not in GROUNDERS.names():
            p.error(f"{model}: unknown grounder {grounder!r} (known: {', '.join(GROUNDERS.names())})")
    from abm.machine import describe_machine

    rows = run(args)
    machine = describe_machine()
    print(f"machine: {machine}; {args.task} ({args.split}), {args.episodes} episodes, "
          f"--max-steps {args.max_steps}, CPU seconds per rollout")
    print(markdown(rows))
    if args.record is not None:
        record(args.record, rows, machine)


def record(path: Path, rows: list[dict[str, Any]], machine: str, now: datetime | None = None) -> None:
    """Append one run's rows to the JSON list at ``path``, each stamped with the run's UTC time and machine;
    earlier rows stay (other runs of the same commits included)."""
    measured = (now or datetime.now(UTC)).strftime("%Y-%m-%dT%H:%M:%SZ")
    old = json.loads(path.read_text()) if path.exists() else []
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(old + [{**r, "measured": measured, "machine": machine} for r in rows], indent=1)
                    + "\n")


if __name__ == "__main__":
    main()
