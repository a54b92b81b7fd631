"""Typed jobs: the work of the experiment engine's stages as data (frozen dataclasses, one per kind).

A job says what to do in typed fields and does it by calling the library function the matching ``abm`` command
calls (:meth:`TypedJob.run`): nothing is passed as a command line. The engine (:mod:`abm.experiments.stages`)
writes each job to ``OUT/jobs/JOB.json`` (:meth:`TypedJob.write`) and hands it to a process that runs
``python -m abm.experiments.jobs OUT/jobs/JOB.json`` (:mod:`abm.experiments.jobs.__main__`), locally or on a Ray
node (:mod:`abm.experiments.scheduler`); that command line is what ``abm experiment status`` looks for among the
live processes.

Each kind calls what its ``abm`` command calls:

* ``data`` (:class:`DataJob`): :func:`abm.data.stores.generate_tasks`, as ``abm data generate``;
* ``ground`` (:class:`GroundJob`): :func:`abm.data.stores.ground_store`, as ``abm data ground``;
* ``train`` (:class:`TrainJob`): :func:`abm.train.loop.train`, then the loss curve, as ``abm train``;
* ``export`` (:class:`ExportJob`): :func:`abm.policy.export.export_model`, as ``abm export``;
* ``eval`` (:class:`EvaluationJob`): :func:`abm.evaluation.session.run_evaluation`, as ``abm eval`` (several
  models' evaluations of a split at once: :func:`abm.evaluation.session.run_evaluations`);
* ``zoo_eval`` (:class:`ZooEvalJob`): :func:`abm.evaluation.session.evaluate_zoo`, as ``abm zoo eval``;
* ``diagnose`` (:class:`DiagnoseJob`): a diagnosis request's ``run`` (:mod:`abm.evaluation.diagnose`).

Every job also names the ``abm`` command that does the same (:meth:`TypedJob.command`), which ``abm experiment run
--dry-run`` prints and a person can run by hand; tests parse it with abm's own parser, so a renamed flag fails
there and not in a running experiment.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar, Self, get_type_hints

from abm.data.stores import generate_tasks, ground_store
from abm.errors import ConfigError
from abm.evaluation.diagnose import from_dict as diagnosis_from_dict
from abm.evaluation.diagnose.request import DiagnosisRequest
from abm.evaluation.plots import run_loss_curves
from abm.evaluation.session import EvalRequest, evaluate_zoo, run_evaluations
from abm.evaluation.settings import ZOO_EVAL_EPISODES, ZOO_EVAL_MAX_STEPS, ZOO_EVAL_TASKS
from abm.geometry import Workspace
from abm.policy.config import PolicyConfig
from abm.policy.export import export_model
from abm.registry import Registry
from abm.serialize import json_value, typed_value
from abm.train.config import TrainConfig
from abm.train.loop import train


class TypedJob:
    """One job of an experiment (a frozen dataclass subclass; its kind in :data:`JOBS` is :attr:`kind`)."""

    kind: ClassVar[str]

    def run(self) -> None:
        """Do the work (in this process), by the library function its ``abm`` command calls."""
        raise NotImplementedError

    def command(self) -> list[str] | None:
        """The words of the ``abm`` command that does the same (after ``abm``), for a person to read or run
        (``None``: no ``abm`` command does it)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """``{"kind": KIND, FIELD: value, ...}`` in JSON types."""
        return {"kind": self.kind, **{f.name: json_value(getattr(self, f.name)) for f in fields(self)}}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        """The job :meth:`to_dict` wrote.

        Raises:
            ConfigError: another kind, a key the job does not have, or a field missing.
        """
        values = dict(data)
        kind = values.pop("kind", cls.kind)
        names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        if kind != cls.kind or not set(values) <= names:
            raise ConfigError(f"not a job of kind {cls.kind!r}: kind {kind!r}, keys {', '.join(sorted(values))} (it "
                              f"has {', '.join(sorted(names))})")
        hints = get_type_hints(cls)
        try:
            return cls(**{k: typed_value(hints[k], v) for k, v in values.items()})
        except TypeError as err:  # a field missing
            raise ConfigError(f"a job of kind {cls.kind!r}: {err}") from None

    def write(self, path: Path) -> None:
        """Write the job to ``path`` (JSON; its folder made)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")


#: every kind of job, by name (:attr:`TypedJob.kind`)
JOBS: Registry[type[TypedJob]] = Registry("job kind")


def _register(cls: type[TypedJob]) -> type[TypedJob]:
    return JOBS.register(cls.kind, cls)


def read_job(path: Path) -> TypedJob:
    """The job written to ``path`` (:meth:`TypedJob.write`).

    Raises:
        UnknownNameError: its kind is none of :data:`JOBS`; ConfigError: it does not read as that kind.
    """
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ConfigError(f"{path}: not a job file ({err})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: not a job file (a JSON object with its kind)")
    return JOBS[data.get("kind")].from_dict(data)  # type: ignore[index]


@_register
@dataclass(frozen=True)
class DataJob(TypedJob):
    """Demonstrations of ``tasks`` on ``split`` in the store ``out`` (see :func:`abm.data.stores.generate_tasks`)."""

    kind: ClassVar[str] = "data"
    tasks: tuple[str, ...]
    split: str
    episodes: int
    out: Path
    workers: int = 1
    seed: int = 0
    resolution: int = 128
    backend: str = "local"
    ray_address: str | None = None

    def run(self) -> None:
        generate_tasks(self.tasks, self.split, self.episodes, self.out, workers=self.workers, seed=self.seed,
                       resolution=self.resolution, backend=self.backend, ray_address=self.ray_address)

    def command(self) -> list[str]:
        backend = ["--backend", self.backend] if self.backend != "local" else []
        return ["data", "generate", "--task", ",".join(self.tasks), "--split", self.split, "--episodes",
                str(self.episodes), "--out", self.out.as_posix(), "--workers", str(self.workers), "--seed",
                str(self.seed), "--resolution", str(self.resolution), *backend,
                *(["--ray-address", self.ray_address] if self.ray_address else [])]


@_register
@dataclass(frozen=True)
class GroundJob(TypedJob):
    """The CLIP mask fields (or, ``features``, point features) of the store ``data``'s keyframes into ``cache``
    (see :func:`abm.data.stores.ground_store`), in the policy's workspace cube (``None``: the policy default)."""

    kind: ClassVar[str] = "ground"
    data: Path
    cache: Path
    clip_model: str
    tasks: tuple[str, ...]
    features: bool = False
    workspace_center: tuple[float, ...] | None = None
    workspace_size: float | None = None

    def workspace(self) -> Workspace:
        """The cube the keyframes are grounded in (m)."""
        defaults = PolicyConfig()
        center = self.workspace_center or defaults.workspace_center
        return Workspace((center[0], center[1], center[2]), self.workspace_size or defaults.workspace_size)

    def run(self) -> None:
        ground_store(self.data, self.cache, self.workspace(), clip_model=self.clip_model, features=self.features,
                     tasks=self.tasks)

    def command(self) -> list[str]:
        cube = [*(["--workspace-center", *map(str, self.workspace_center)] if self.workspace_center else []),
                *(["--workspace-size", str(self.workspace_size)] if self.workspace_size is not None else [])]
        return ["data", "ground", "--data", self.data.as_posix(), "--cache", self.cache.as_posix(), "--clip-model",
                self.clip_model, *(["--features"] if self.features else []), "--tasks", *self.tasks, *cube]


@_register
@dataclass(frozen=True)
class TrainJob(TypedJob):
    """One training (:func:`abm.train.loop.train` of ``config``; it resumes from the last checkpoint in its run
    folder when ``config.resume``), then its loss curve (``RUN/training_curve.png``), as ``abm train`` does.
    ``recipe``: the same options as ``abm train --config`` reads them, written beside for a person (the engine's
    ``OUT/recipes/RUN.yaml``)."""

    kind: ClassVar[str] = "train"
    config: TrainConfig
    recipe: Path

    def run(self) -> None:
        train(self.config)
        run_loss_curves({self.config.method: self.config.out}, Path(self.config.out) / "training_curve.png")

    def command(self) -> list[str]:
        return ["train", "--config", self.recipe.as_posix(), "--out", Path(self.config.out).as_posix(),
                *(["--resume"] if self.config.resume else []), *([] if self.config.progress else ["--no-progress"])]


@_register
@dataclass(frozen=True)
class ExportJob(TypedJob):
    """A finished run's checkpoint into the zoo, its weights as ``dtype`` (:func:`abm.policy.export.export_model`)."""

    kind: ClassVar[str] = "export"
    run_dir: Path
    out: Path
    dtype: str = "bfloat16"

    def run(self) -> None:
        export_model(self.run_dir, self.out, self.dtype)

    def command(self) -> list[str]:
        return ["export", "--run", self.run_dir.as_posix(), "--out", self.out.as_posix(), "--dtype", self.dtype]


@_register
@dataclass(frozen=True)
class EvaluationJob(TypedJob):
    """One evaluation (:func:`abm.evaluation.session.run_evaluation`); it resumes from the outcomes its folder
    holds. With ``together`` (other evaluations of the same split, each into its own folder: the engine's other
    models) all are run at once, every scene built once for all of them
    (:func:`abm.evaluation.session.run_evaluations`)."""

    kind: ClassVar[str] = "eval"
    request: EvalRequest
    together: tuple[EvalRequest, ...] = ()

    def run(self) -> None:
        run_evaluations([self.request, *self.together])

    def command(self) -> list[str] | None:
        """``abm eval ...`` of the request (``None`` with ``together``: no one ``abm eval`` writes several
        folders)."""
        if self.together:
            return None
        r, s = self.request, self.request.settings
        words = ["eval", *(w for run in r.runs for w in ("--run", Path(run).as_posix())),
                 *(["--tasks", *r.tasks] if r.tasks else []), "--split", *r.splits, "--episodes", str(r.episodes),
                 "--repeats", str(r.repeats), "--workers", str(r.workers), "--max-steps", str(s.max_steps),
                 "--resolution", str(s.resolution)]
        optional = [("--out", r.out.as_posix() if r.out else None), ("--gifs", str(r.gifs) if r.gifs else None),
                    ("--device", s.device if s.device != "cpu" else None), ("--grounder", s.grounder),
                    ("--clip-model", s.clip_model), ("--expert-keyframes", s.expert_keyframes)]
        return words + [w for flag, value in optional if value for w in (flag, value)]


@_register
@dataclass(frozen=True)
class ZooEvalJob(TypedJob):
    """The zoo's abm and rvt models on seen and unseen objects (:func:`abm.evaluation.session.evaluate_zoo`)."""

    kind: ClassVar[str] = "zoo_eval"
    zoo: Path
    out: Path
    tasks: tuple[str, ...] = ZOO_EVAL_TASKS
    episodes: int = ZOO_EVAL_EPISODES
    max_steps: int = ZOO_EVAL_MAX_STEPS
    models: tuple[str, ...] = ()  #: the zoo's models by name (default: abm zoo eval's choice, abm.zoo.pick)

    def run(self) -> None:
        evaluate_zoo(self.zoo, self.out, self.tasks, self.episodes, max_steps=self.max_steps, models=self.models)

    def command(self) -> list[str]:
        changed = [*(["--tasks", *self.tasks] if self.tasks != ZOO_EVAL_TASKS else []),
                   *(["--episodes", str(self.episodes)] if self.episodes != ZOO_EVAL_EPISODES else []),
                   *(["--max-steps", str(self.max_steps)] if self.max_steps != ZOO_EVAL_MAX_STEPS else []),
                   *(["--models", *self.models] if self.models else [])]
        return ["zoo", "eval", "--zoo", self.zoo.as_posix(), "--out", self.out.as_posix(), *changed]


@_register
@dataclass(frozen=True)
class DiagnoseJob(TypedJob):
    """One diagnosis: its request (:mod:`abm.evaluation.diagnose`) measures and writes its file."""

    kind: ClassVar[str] = "diagnose"
    request: DiagnosisRequest

    def run(self) -> None:
        self.request.run()

    def command(self) -> None:
        """A diagnosis has no ``abm`` command (``benchmarks/`` has a script for a person to run by hand)."""
        return None

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Self:
        if data.get("kind", cls.kind) != cls.kind or set(data) - {"kind", "request"}:
            raise ConfigError(f"not a job of kind 'diagnose': keys {', '.join(sorted(data))} (it has kind, request)")
        return cls(diagnosis_from_dict(data["request"]))
