"""An experiment as data: :class:`ExperimentSpec` and its YAML loader (``configs/experiments/NAME.yaml``).

A spec names everything a pipeline driver used to hold in a shell script and a report writer: the
demonstrations to generate, the runs as typed overrides of the training recipe, the evaluation protocol, the
diagnosis, the report's tables and figures, and the resources (trainings at a time, threads each). The engine
(:mod:`abm.experiments.stages`) runs it; :mod:`abm.experiments.report` writes its generated blocks.

Paths in a spec are relative to the root the engine runs in (the repository checkout). :func:`load_spec`
validates the whole file before any work starts; a mistake is one :class:`SpecError` naming the file and the
key (``configs/experiments/x.yaml: runs.abm.train.steps: expected a whole number >= 1, got 'many'``).
"""

from __future__ import annotations

import argparse
import functools
import re
import string
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath
from typing import Any, Protocol

from abm.configuration import (
    CAMERA_RESOLUTION,
    MAX_KEYFRAMES,
    SPLITS,
    WORKERS,
    builtin_or_file,
    check_recipe,
    field_check,
    flag_check,
    load_recipe,
    settable_fields,
)
from abm.errors import ConfigError
from abm.evaluation.settings import EXPERT_KEYFRAME_KINDS
from abm.experiments.report.kinds import SECTIONS
from abm.files import load_yaml
from abm.grounding.config import GROUNDERS
from abm.policy.config import PolicyConfig
from abm.policy.language_config import LANGUAGES
from abm.policy.variants import VARIANTS
from abm.schema import Reader, shown
from abm.train.config import TrainConfig

#: the built-in specs (``abm experiment run paper_tables``; the repository's configs/experiments/ links here)
SPECS = Path(__file__).resolve().parent.parent / "configs" / "experiments"
#: the engine's stages, in order (``abm experiment run --stages``); ``carry`` runs only when asked for
STAGES: tuple[str, ...] = ("data", "ground", "train", "export", "eval", "diagnose", "report")
EXTRA_STAGES: tuple[str, ...] = ("carry",)
#: TrainConfig fields the engine sets itself for every run (a spec may not override them)
ENGINE_TRAIN_FIELDS = ("out", "data", "resume", "overwrite", "progress", "cache_dir")
POLICY_FIXED = ("variant", "preset", "extra")  #: PolicyConfig fields set by the run's method and preset
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_MARKER = re.compile(r"^[a-z0-9][a-z0-9-]*$")


class SpecError(ConfigError):
    """An experiment spec that does not load: the message names the file and the key."""


@dataclass(frozen=True)
class DataSpec:
    """The demonstrations to generate (``abm data generate``), one episode store for every task.

    Attributes:
        tasks: tasks to demonstrate.
        split: object split of the demonstrations.
        episodes: successful demonstrations per task.
        workers: parallel generator processes.
        seed: first scene seed.
        resolution: camera image side (pixels).
        folder: the episode store (relative to the root; default ``OUT/data``).
    """

    tasks: tuple[str, ...]
    split: str = "seen"
    episodes: int = 20
    workers: int = WORKERS
    seed: int = 0
    resolution: int = CAMERA_RESOLUTION
    folder: str | None = None


@dataclass(frozen=True)
class RunSpec:
    """One training run: a name, what the report calls it, and what it trains.

    Attributes:
        name: the run's folder under OUT and its file in the zoo (``ZOO/NAME.pt``).
        label: its row label in the report's tables.
        grounding: what grounds its target, as the report and the zoo index say it (``oracle``,
            ``clip``, ``none (CLIP text)``, ...).
        config: its training options: the recipe with the spec's common and the run's own ``train`` and ``policy``
            overrides (:class:`~abm.train.config.TrainConfig` and its nested
            :class:`~abm.policy.config.PolicyConfig`; a run that names no grounder trains with the oracle, the
            TrainConfig default), the spec's CLIP in the grounder and language encoder that take one. The engine
            sets the run folder, data, cache and resuming (:meth:`ExperimentSpec.train_config`).
        caveat: a sentence the report prints under the tables while the run has cells.
    """

    name: str
    label: str
    grounding: str
    config: TrainConfig
    caveat: str = ""

    @property
    def method(self) -> str:
        """The policy variant (``abm``, ``rvt``, ``ifd``, an ablation)."""
        return self.config.method

    @property
    def grounder(self) -> str:
        """The training grounder's kind (``oracle`` or ``clip``: :data:`abm.grounding.config.GROUNDERS`)."""
        return self.config.grounder.kind

    @property
    def language(self) -> str:
        """The language encoder's kind (``hash`` or ``clip``; by default the grounder's:
        :attr:`abm.train.config.TrainConfig.language_config`)."""
        return self.config.language_config.kind

    @property
    def needs_clip(self) -> bool:
        """Whether training or evaluating the run needs the benchmark CLIP (its grounder or language encoder
        takes CLIP weights)."""
        return needs_clip(self.config)

    @property
    def cache(self) -> str | None:
        """The grounding cache the run trains from: ``features`` (the CLIP point features of a variant that fuses
        them, :attr:`~abm.policy.variants.VariantSpec.clip_features`), ``masks`` (the CLIP mask field) or ``None``
        (a grounder whose kind is not ``cached``, the oracle, needs none)."""
        if not GROUNDERS[self.grounder].cached:
            return None
        return "features" if self.config.policy.spec.clip_features else "masks"


def needs_clip(config: TrainConfig) -> bool:
    """Whether the grounder or the language encoder of ``config`` takes CLIP weights."""
    return GROUNDERS[config.grounder.kind].clip or LANGUAGES[config.language_config.kind].clip


class RunPaths(Protocol):
    """Where the engine puts a run's files (:class:`abm.experiments.state.Layout` is one)."""

    @property
    def data(self) -> Path: ...

    def run_dir(self, run: str) -> Path: ...

    def cache(self, kind: str) -> Path: ...

    def show(self, path: Path) -> str: ...


@dataclass(frozen=True)
class TrainingSpec:
    """What every run shares.

    Attributes:
        recipe: the training recipe (``abm train --config``: a built-in name or a YAML file, relative to the
            working folder); read when the spec loads, into every run's :attr:`RunSpec.config`.
        tasks: the tasks every run trains on (default: all in the episode store).
        steps: optimiser steps of every run (default: the recipe's).
    """

    recipe: str
    tasks: tuple[str, ...] | None = None
    steps: int | None = None


@dataclass(frozen=True)
class EvalSplit:
    """One object split of the evaluation.

    Attributes:
        split: ``seen``, ``unseen`` or ``compositional``.
        tasks: tasks evaluated on it.
        runs: the runs (and variants) evaluated on it (default: all).
    """

    split: str
    tasks: tuple[str, ...]
    runs: tuple[str, ...] | None = None


@dataclass(frozen=True)
class GrounderVariant:
    """A run evaluated with other evaluation settings than its own, an arm without a training: another grounder
    than it was trained with (``abm eval --grounder``), or the scripted expert's keyframes of a kind instead of
    the policy's (``abm eval --expert-keyframes``).

    Attributes:
        name: its folder under OUT/eval (``RUN@GROUNDER`` for a grounder alone, else any plain name).
        run: the trained run.
        grounder: the grounder at evaluation (``clip``, ``oracle`` or ``tracking``; ``""``: the run's own).
        label: its row label in the report.
        description: what grounds its target, in the report.
        expert_keyframes: the keyframe kind the expert executes instead of the policy (``move``; ``""``: none).
    """

    name: str
    run: str
    grounder: str
    label: str
    description: str = ""
    expert_keyframes: str = ""


@dataclass(frozen=True)
class EvaluationSpec:
    """The evaluation protocol (``abm eval``): the same seeded scenes for every run.

    Attributes:
        episodes: seeded episodes per task, split and repeat.
        repeats: repeats with different scenes.
        workers: parallel rollout processes per evaluation.
        max_steps: keyframes per episode.
        gifs: front-camera GIFs saved per task.
        from_zoo: evaluate the exported zoo file (``ZOO/RUN.pt``) instead of the run folder.
        splits: the object splits and their tasks.
        variants: runs evaluated with another grounder.
        zoo_eval: time ``abm zoo eval`` once these runs are in the zoo (empty: never).
        device: torch device of the evaluated policies (cpu, cuda).
    """

    episodes: int = 25
    repeats: int = 1
    workers: int = WORKERS
    max_steps: int = MAX_KEYFRAMES
    gifs: int = 0
    from_zoo: bool = False
    splits: tuple[EvalSplit, ...] = ()
    variants: tuple[GrounderVariant, ...] = ()
    zoo_eval: tuple[str, ...] = ()
    device: str = "cpu"

    def split_runs(self, split: EvalSplit, runs: Sequence[str]) -> list[str]:
        """The runs and variants evaluated on ``split``, in spec order."""
        names = [*runs, *(v.name for v in self.variants)]
        return [n for n in names if split.runs is None or n in split.runs]


@dataclass(frozen=True)
class DiagnoseSpec:
    """Teacher-forced keyframe accuracy of every run on expert scenes (``benchmarks/keyframe_accuracy.py``).

    Attributes:
        episodes: evaluation scenes per task and split.
        splits: object splits.
        tasks: tasks (default: the training tasks).
        oracle_mask: also score every CLIP-grounded mask run with the simulator's mask (``RUN@oracle``).
        steps: also score these checkpoint steps of each run (keyframe error against training time).
        kinds: keyframe kinds to print (all are stored).
        skill_text: also run the skill-text probe (``benchmarks/skill_text_probe.py``) on the runs that read a
            skill text (``None``: not part of the diagnosis).
        destination_grounding: also measure how well the spec's CLIP grounds each task's destination beside its
            target (``benchmarks/destination_grounding.py``), once per spec (``None``: not part of the diagnosis).
    """

    episodes: int = 5
    splits: tuple[str, ...] = ("seen", "unseen")
    tasks: tuple[str, ...] | None = None
    oracle_mask: bool = False
    steps: tuple[int, ...] = ()
    kinds: tuple[str, ...] = ()
    skill_text: SkillTextSpec | None = None
    destination_grounding: DestinationGroundingSpec | None = None


@dataclass(frozen=True)
class SkillTextSpec:
    """The skill-text probe of the diagnosis: does a mask policy carry to the destination its skill text names?

    Attributes:
        tasks: the tasks probed, one job per run and task (``place_wine``, ``pick_block``).
        kind: the keyframe kind probed (``move``: the carry to the destination only the skill text names).
        episodes: evaluation scenes per task (teacher-forced on the expert's rollout).
        split: their object split.
        runs: the runs probed (default: every run whose variant reads a skill text: abm and the ablations).
        within_cm: the target: the prediction with the scene's own skill text within this distance (cm) of the
            expert's keyframe (the report checks it).
    """

    tasks: tuple[str, ...]
    kind: str = "move"
    episodes: int = 5
    split: str = "seen"
    runs: tuple[str, ...] = ()
    within_cm: float = 5.0


@dataclass(frozen=True)
class DestinationGroundingSpec:
    """The destination's grounding quality in the diagnosis (the ``destination_grounding`` diagnosis,
    :class:`abm.evaluation.diagnose.destination_grounding.DestinationGrounding`): the spec's CLIP grounder (its
    default configuration) on each task's target X and destination, scored against the simulator's segmentation.
    It measures the grounder, not a run: one job per spec (``diagnose/destination_grounding``), kept as
    ``KEPT/destination_grounding.json``.

    Attributes:
        episodes: evaluation scenes per task and split (first observation).
        splits: their object splits.
        tasks: the tasks measured (default: the diagnosis' tasks; one without a destination has target rows only).
    """

    episodes: int = 5
    splits: tuple[str, ...] = ("seen", "unseen")
    tasks: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Resources:
    """How the trainings share the machine.

    Attributes:
        trainings_at_a_time: trainings run side by side.
        threads_each: torch threads of each training (a training left alone gets the others' too).
        order: training order (default: the runs' order).
    """

    trainings_at_a_time: int = 2
    threads_each: int = 1
    order: tuple[str, ...] = ()


@dataclass(frozen=True)
class Section:
    """One part of the report (see :data:`abm.experiments.report.kinds.SECTIONS` for what each kind takes).

    Attributes:
        kind: what it writes (``setup``, ``per_task``, ``per_run``, ``averages``, ``spread``, ``targets``,
            ``caveats``, ``weakest_keyframes``, ``approach_yaw``, ``zoo_eval``, ``text``, ``detail``,
            ``keyframe_accuracy``, ``keyframe_table``, ``figures``, ``heading``, ``outcome_tables``, ``seeds``,
            ``diagnosis``, ``loops``: grasp <-> lift loops per row and split).
        title: a paragraph before a table.
        text: the paragraph of ``text`` / ``heading`` or the template of ``spread`` / ``targets``.
        runs: rows (or columns) of a table, in order.
        splits: object splits of a table.
        table: the table's number in the records (``paper_tables.json``).
        names: row names replacing a run's name.
        paper: the paper's averages per run (one per split).
        of_table: the table a ``spread`` sentence summarises, a ``seeds`` section measures, or whose seed spread a
            ``headline`` text holds its differences to (:func:`headline_fields`).
        checks: the ``targets`` checks.
        task: the task an ``approach_yaw`` sentence names.
        note: a sentence appended to the section.
        digits: decimals of averages (tables).
        column: the header of a table's first column.
        show: what a ``setup`` paragraph states, in order (:data:`SETUP_ITEMS`).
        describe: a ``success_rows`` table also names each row's method and what grounds its target.
        kinds: keyframe kinds of a keyframe table.
        sentences: the ``sentences`` of a comparison.
        source: the JSON a ``grounding_quality`` table reads (relative to the root).
        config: the grounding configuration it shows.
        spread: a table's averages also show their standard error over the repeats (cells show mean ± std).
        seeds: run -> the same run with another seed (a ``seeds`` section: their difference is the seed spread).
        explain: a ``targets`` section measures a miss against the seed spread, and a ``target_diagnosis``
            section says, for each target it misses, what the run's diagnosis shows.
        earlier: an ``editions`` table's earlier editions: label -> their records JSON (relative to the root), oldest
            first.
        only: ``readme``: the section is written into the README block only; ``document``: into the document
            only; "" (default): into both.
    """

    kind: str
    title: str = ""
    text: str = ""
    runs: tuple[str, ...] = ()
    splits: tuple[str, ...] = ()
    table: int | None = None
    names: Mapping[str, str] = field(default_factory=dict)
    paper: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    of_table: int | None = None
    checks: tuple[TargetCheck, ...] = ()
    task: str = ""
    note: str = ""
    digits: int = 1
    column: str = ""
    show: tuple[str, ...] = ()
    describe: bool = False
    kinds: tuple[str, ...] = ()
    sentences: tuple[Sentence, ...] = ()
    source: str = ""
    config: str = ""
    spread: bool = False
    seeds: Mapping[str, str] = field(default_factory=dict)
    explain: bool = False
    earlier: Mapping[str, str] = field(default_factory=dict)
    only: str = ""


@dataclass(frozen=True)
class Sentence:
    """A sentence comparing two rows' averages, written once both have seen and unseen averages.

    Attributes:
        text: the template: ``{a}`` and ``{b}`` name the rows, ``{a_seen}``, ``{a_unseen}``, ``{b_seen}``,
            ``{b_unseen}`` are their averages (%), ``{ratio_seen}`` and ``{ratio_unseen}`` are b / a.
        runs: the two rows ``a`` and ``b``.
    """

    text: str
    runs: tuple[str, str]


@dataclass(frozen=True)
class TargetCheck:
    """One target of a ``targets`` section, checked on a run's split averages.

    Attributes:
        text: how the report states it (``seen ≥ 60 %``).
        kind: ``at_least`` (the split average ≥ ``value``), ``ratio`` (unseen / seen ≥ ``value``), ``beats``
            (the split average ≥ ``base``'s + ``value``), ``below`` (the split average < ``value`` × ``base``'s),
            ``keyframe_cm`` / ``keyframe_deg`` (the diagnosis's median position error, cm, / rotation error, °, of
            ``keyframe`` on the split, the median over the tasks of each task's median, ≤ ``value``) or
            ``loops`` (the share of the split's episodes with a grasp <-> lift loop,
            :func:`abm.experiments.arm_records.loops`, ≤ ``value`` %); or, of the section rather than of a row,
            ``exceeds_spread`` (every difference between the split averages of two rows named in ``pairs`` larger
            than the seed spread of table ``of_table`` on the split, as that table's ``seeds`` sections measure
            it, plus ``value`` points, default 0).
        split: the split it is checked on.
        value: the threshold, ratio or margin.
        base: the run compared with (``beats``, ``below``).
        run: the only row it is checked on (default: every row of the section).
        keyframe: the keyframe kind of ``keyframe_cm`` / ``keyframe_deg`` (``move``).
        pairs: the differences an ``exceeds_spread`` check names, each two rows of table ``of_table``.
        of_table: the table whose rows and seed spread an ``exceeds_spread`` check reads.
    """

    text: str
    kind: str
    split: str
    value: float
    base: str = ""
    run: str = ""
    keyframe: str = ""
    pairs: tuple[tuple[str, str], ...] = ()
    of_table: int | None = None


@dataclass(frozen=True)
class FigureSpec:
    """A figure drawn from the kept outcomes (:mod:`abm.evaluation.plots`).

    Attributes:
        kind: ``success`` (bar chart per task and split), ``losses`` (training loss curves) or
            ``keyframe_error`` (grasp keyframe error against training steps).
        file: the PNG (relative to the root).
        alt: its alt text.
        runs: runs (and variants) drawn (default: all).
    """

    kind: str
    file: str
    alt: str
    runs: tuple[str, ...] = ()


@dataclass(frozen=True)
class ReportSpec:
    """What the report stage writes.

    Attributes:
        title: the heading of the document.
        document: the full report (markdown, relative to the root).
        records: the machine-readable cells (JSON), or "" for none.
        arm_records: every arm's keyframe accuracy, rollouts and grasp <-> lift loops (JSON:
            :mod:`abm.experiments.arm_records`), or "" for none.
        readme: the file holding the generated block, or "" for none.
        block: the block's marker name (``<!-- NAME:start -->`` ... ``<!-- NAME:end -->``).
        blocks: further blocks of the same README, marker name -> their sections (e.g. a ``headline`` block at
            the top of the README: no provenance line and no link to the document, just their sections).
        summary: sections of the README block and the document's top.
        details: sections of the document only.
        figures: figures drawn from the kept outcomes.
        zoo_readme: also write the zoo's index and README (``ZOO/index.json``, ``ZOO/README.md``).
        zoo_note: what the zoo's README says about its models after naming what wrote it.
        readme_when: when the README's blocks and the zoo's README are written (``None``: every time the report
            runs); until then the report leaves them as they are (another edition's).
    """

    title: str
    document: str
    records: str = ""
    readme: str = ""
    block: str = ""
    arm_records: str = ""
    summary: tuple[Section, ...] = ()
    details: tuple[Section, ...] = ()
    blocks: Mapping[str, tuple[Section, ...]] = field(default_factory=dict)
    figures: tuple[FigureSpec, ...] = ()
    zoo_readme: bool = False
    zoo_note: str = ""
    readme_when: ReadmeGate | None = None


@dataclass(frozen=True)
class ReadmeGate:
    """The gate of a report's README blocks and zoo README (``report.readme_when``): a spec declares them before
    it has results, and the report writes them only once the gate is open, so an edition that has not run leaves
    the README and the zoo's README to the edition before (:mod:`abm.experiments.report.gate`).

    Attributes:
        complete: the tables (their ``table:`` numbers) that must have every cell evaluated first: every row on
            every task of each split of the table, and the runs of the table's seed pairs (its ``seeds``
            sections) on theirs, so the README's differences can be held to the seed spread.
    """

    complete: tuple[int, ...]


@dataclass(frozen=True)
class ExperimentSpec:
    """One experiment (``configs/experiments/NAME.yaml``).

    Attributes:
        name: the experiment's name (``abm experiment run NAME``).
        path: the file it was loaded from.
        about: what it measures (one paragraph).
        out: the working folder (relative to the root; not committed).
        kept: the committed outcomes (evaluations, diagnoses, stage times, machines, run summaries): a fresh
            clone restores them into OUT, so nothing finished runs twice and the report has every row.
        zoo: export every finished run here (``ZOO/RUN.pt``, ``ZOO/RUN{zoo_suffix}.pt``), or "" for no export.
        zoo_suffix: appended to every run's name in the zoo (file and index entry), so a later edition of an
            experiment exports beside the earlier one's models instead of replacing them (``_v2``).
        edition: the edition of the experiment's models in the zoo (1: the first; a later edition's entries
            record it, and ``abm zoo eval`` prefers the newest edition's compared models: :func:`abm.zoo.pick`).
        carry: the committed state of unfinished trainings and evaluations (for a continuation elsewhere),
            or "" for none.
        clip: the benchmark CLIP folder (for runs that need it).
        clip_command: how the benchmark CLIP was trained (the zoo index says so).
        data: the demonstrations.
        training: what every run shares.
        runs: the runs, in report order.
        evaluation: the evaluation protocol.
        diagnose: the diagnosis (``None``: no diagnosis stage).
        resources: trainings at a time, threads each.
        report: what the report writes.
        finished: the experiment is finished and its outcomes kept; its trainings are not run again (their
            checkpoints are gone): says when it ran and where its numbers are. Only its report runs (from them).
    """

    name: str
    path: Path
    about: str
    out: str
    kept: str
    data: DataSpec
    training: TrainingSpec
    runs: Mapping[str, RunSpec]
    evaluation: EvaluationSpec
    report: ReportSpec
    zoo: str = ""
    carry: str = ""
    clip: str = ""
    clip_command: str = ""
    diagnose: DiagnoseSpec | None = None
    resources: Resources = field(default_factory=Resources)
    zoo_suffix: str = ""
    edition: int = 1
    finished: str = ""

    def run_names(self) -> list[str]:
        """Every run, in report order."""
        return list(self.runs)

    def training_order(self) -> list[str]:
        """Every run, in training order (:attr:`Resources.order`, then the rest)."""
        first = [r for r in self.resources.order if r in self.runs]
        return first + [r for r in self.runs if r not in first]

    def tables_of(self, run: str) -> list[int]:
        """The numbers of the report tables ``run`` has a row in."""
        sections = (*self.report.summary, *self.report.details)
        return sorted({s.table for s in sections if s.table is not None and run in s.runs})

    def diagnoses(self) -> list[str]:
        """Names of the diagnosis files: every run, and every CLIP-grounded mask run fed the oracle mask
        (``RUN@oracle``) when :attr:`DiagnoseSpec.oracle_mask` is set."""
        if self.diagnose is None:
            return []
        names = []
        for name, run in self.runs.items():
            names.append(name)
            if self.diagnose.oracle_mask and run.cache == "masks":
                names.append(name + ORACLE_MASK)
        return names

    def zoo_name(self, run: str) -> str:
        """The run's name in the zoo (``RUN`` + :attr:`zoo_suffix`)."""
        return run + self.zoo_suffix

    def probes(self) -> list[tuple[str, str]]:
        """``(run, task)`` of every skill-text probe of the diagnosis, in spec order."""
        probe = self.diagnose.skill_text if self.diagnose is not None else None
        if probe is None:
            return []
        return [(run, task) for run in self.runs if run in probe.runs for task in probe.tasks]

    def split_tasks(self) -> dict[str, tuple[str, ...]]:
        """The evaluation's tasks per split."""
        return {s.split: s.tasks for s in self.evaluation.splits}

    def train_config(self, run: str, paths: RunPaths, clip_model: str | None = None) -> TrainConfig:
        """What the engine trains for ``run``: :attr:`RunSpec.config` with the engine's settings: the run folder,
        the episode store and the grounding cache (:attr:`RunSpec.cache`) of ``paths``, as the root-relative paths
        the engine's jobs run under (``paths.show``), resuming from a checkpoint, no progress bar; ``clip_model``
        (``abm quickstart``'s CLIP) replaces the spec's CLIP where the run takes one."""
        spec_run = self.runs[run]
        config = spec_run.config
        if clip_model and spec_run.needs_clip:
            config = config.with_clip(clip_model)
        cache = paths.show(paths.cache(spec_run.cache)) if spec_run.cache else None
        return replace(config, out=Path(paths.show(paths.run_dir(run))), data=Path(paths.show(paths.data)),
                       cache_dir=Path(cache) if cache else None, resume=True, progress=False)


ORACLE_MASK = "@oracle"  #: suffix of a diagnosis with the simulator's mask instead of the run's own


# ------------------------------------------------------------------------------------------------ reading
class _Reader(Reader):
    """A spec's mapping, read by the YAML validator (:class:`abm.schema.Reader`; every error a :class:`SpecError`
    naming the file and the key path), with the kinds of value only specs have: paths inside the root, values
    checked as an ``abm`` command's option checks them, task lists."""

    def __init__(self, data: Any, source: str | Path, where: str = "", error: Any = SpecError,
                 keys: Sequence[str] = ()) -> None:
        super().__init__(data, source, where, error, keys)

    def flag_value(self, key: str, default: Any, command: str, dest: str) -> Any:
        """``key``, checked as the option ``dest`` of ``abm COMMAND`` checks its value on the command line (its
        own type, range and choices: :func:`abm.configuration.flag_check`), so a spec cannot hand a job a value
        its flag refuses."""
        action = next(a for a in command_parser(command)._actions if a.dest == dest)
        return self.value(key, flag_check(action, f"abm {command} {action.option_strings[0]}"), default)

    def path(self, key: str, default: str | None = "", folder: bool = False) -> str:
        """A path of the spec: relative to the root and inside it (no ``..``, not absolute); a ``folder`` the
        engine writes in is not the root itself (``''`` or ``.``). ``''`` stays "none" where that is the default."""
        value = self.text(key, default)
        if value == "" and default == "":
            return value
        pure = PurePosixPath(value)
        if "\0" in value or pure.is_absolute() or ".." in pure.parts or "\\" in value:
            raise self.error(f"{value!r} leaves the root: give a path relative to the root (--root), without '..'",
                             key)
        if (folder or not value) and str(pure) == ".":
            raise self.error(f"{value!r} is the root itself (the checkout): give a folder inside it, e.g. "
                             f"{default or 'runs/NAME'!r}", key)
        return value

    def optional_integer(self, key: str, low: int = 1) -> int | None:
        return None if self.raw(key) is None else self.integer(key, low=low)

    def tasks(self, key: str, lists: Mapping[str, tuple[str, ...]]) -> tuple[str, ...]:
        """A list of names, or the name of one of the spec's named task lists."""
        value = self.raw(key)
        if not isinstance(value, str):
            return self.names(key)
        if value not in lists:
            raise self.error(f"{value!r} is no task list of this spec (known: {', '.join(lists) or 'none'})", key)
        return lists[value]


def _recipe(reader: _Reader, name: str) -> dict[str, Any]:
    """The values of the training recipe ``name`` (``reader``'s ``recipe``), each checked and converted as
    ``abm train --config`` does (:func:`abm.configuration.check_recipe`), the policy's under ``policy``."""
    parser = command_parser("train")
    try:
        checked = check_recipe(parser, load_recipe(name), f"recipe {name}")
    except ConfigError as err:
        raise reader.error(str(err), "recipe") from None
    sections = parser.get_default("config_sections") or {}
    values: dict[str, Any] = {}
    for action, value in checked:
        section = next((key for key, prefix in sections.items() if action.dest.startswith(prefix)), None)
        if section is None:
            values[action.dest] = value
        else:
            values.setdefault(section, {})[action.dest.removeprefix(sections[section])] = value
    return values


def _checked(reader: _Reader, key: str, cls: type, forbidden: Sequence[str] = ()) -> dict[str, Any]:
    """``reader[key]``: overrides of the config dataclass ``cls``, each key a settable field, each value checked as
    its flag checks it (:func:`abm.configuration.field_check`)."""
    sub = reader.sub(key)
    for name in forbidden:
        if sub.has(name):
            raise sub.error("is set by the engine for every run; remove it from the spec", name)
    fields = [name for name in settable_fields(cls) if name not in forbidden]
    sub.done(fields)
    return {name: sub.value(name, field_check(cls, name)) for name in sub.data}


# --------------------------------------------------------------------------------------------- sections
#: what a ``setup`` paragraph can state (default: machines, recipe, minutes, stages, evaluation)
SETUP_ITEMS = ("machines", "data", "clip", "recipe", "minutes", "speed", "stages", "evaluation", "keyframes")
TARGET_KINDS = ("at_least", "ratio", "beats", "below", "keyframe_cm", "keyframe_deg", "loops", "exceeds_spread")
SPREAD_CHECK = "exceeds_spread"  #: the target kind checked on a table's differences, not on a row
FIGURE_KINDS = ("success", "losses", "keyframe_error")


def _section(reader: _Reader, runs: Sequence[str]) -> Section:
    kind = reader.choice("kind", list(SECTIONS))
    allowed = SECTIONS[kind].keys
    for key in reader.data:
        if key not in ("kind", "only") and key not in allowed:
            raise reader.error(f"a {kind!r} section takes {', '.join(allowed) or 'no other key'}", key)
    known = set(runs)
    section_runs = reader.names("runs", ()) if "runs" in allowed else ()
    for r in section_runs:
        if r not in known:
            raise reader.error(f"{r!r} is no run of this spec (known: {', '.join(runs)})", "runs")
    splits = reader.names("splits", ()) if "splits" in allowed else ()
    for s in splits:
        if s not in SPLITS:
            raise reader.error(f"{s!r} is no object split ({', '.join(SPLITS)})", "splits")
    paper: dict[str, tuple[float, ...]] = {}
    if reader.has("paper"):
        sub = reader.sub("paper")
        for run, values in sub.data.items():
            if run not in known:
                raise sub.error(f"{run!r} is no run of this spec", run)
            values = values if isinstance(values, list) else [values]
            if not values or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
                raise sub.error(f"expected a number per split, got {shown(values)}", run)
            paper[run] = tuple(float(v) for v in values)
            sub.used.add(run)
    names: dict[str, str] = {}
    if reader.has("names"):
        sub = reader.sub("names")
        names = {k: sub.text(k) for k in list(sub.data)}
    seeds: dict[str, str] = {}
    if reader.has("seeds"):
        sub = reader.sub("seeds")
        for run in list(sub.data):
            other = sub.text(run)
            if run not in known or other not in known or run == other:
                raise sub.error(f"expected two different runs of this spec, got {run!r}: {other!r}", run)
            seeds[run] = other
    earlier: dict[str, str] = {}
    if reader.has("earlier"):
        sub = reader.sub("earlier")
        earlier = {label: sub.path(label) for label in list(sub.data)}
        if not earlier or not all(earlier.values()):
            raise reader.error("expected earlier editions as LABEL: RECORDS_JSON (oldest first)", "earlier")
    checks: tuple[TargetCheck, ...] = ()
    if reader.has("checks"):
        raw = reader.raw("checks")
        if not isinstance(raw, list):
            raise reader.error(f"expected a list of checks, got {shown(raw)}", "checks")
        items = []
        for i, item in enumerate(raw):
            c = reader.at(item, f"checks[{i}]")
            check_kind = c.choice("kind", TARGET_KINDS)
            spread_check = check_kind == SPREAD_CHECK
            check = TargetCheck(text=c.text("text"), kind=check_kind, split=c.choice("split", SPLITS),
                                value=c.number("value", 0.0 if spread_check else None), base=c.text("base", ""),
                                run=c.text("run", ""), keyframe=c.text("keyframe", ""),
                                pairs=_pairs(c, known) if spread_check else (),
                                of_table=c.optional_integer("of_table") if spread_check else None)
            if spread_check and (not check.pairs or check.of_table is None or check.run):
                raise c.error("an exceeds_spread check names its pairs ([[RUN, RUN], ...]) and the table whose seed "
                              "spread they are held to (of_table), and no run", "pairs")
            if (check.kind in ("keyframe_cm", "keyframe_deg")) != bool(check.keyframe):
                raise c.error(f"a keyframe kind goes with a keyframe_cm or keyframe_deg check, not {check.kind}",
                              "keyframe")
            if check.kind in ("beats", "below") and check.base not in known:
                raise c.error(f"expected a run of this spec, got {check.base!r}", "base")
            if check.run and check.run not in section_runs:
                raise c.error(f"expected a row of this section, got {check.run!r}", "run")
            c.done()
            items.append(check)
        checks = tuple(items)
    sentences = []
    raw_sentences = reader.raw("sentences", [])
    if not isinstance(raw_sentences, list):
        raise reader.error(f"expected a list of sentences, got {shown(raw_sentences)}", "sentences")
    for i, item in enumerate(raw_sentences):
        c = reader.at(item, f"sentences[{i}]")
        pair = c.names("runs")
        if len(pair) != 2 or any(r not in known for r in pair):
            raise c.error(f"expected two runs of this spec, got {list(pair)}", "runs")
        sentences.append(Sentence(text=c.text("text"), runs=(pair[0], pair[1])))
        c.done()
    show = reader.names("show", ()) if "show" in allowed else ()
    for item in show:
        if item not in SETUP_ITEMS:
            raise reader.error(f"{item!r} is not something a setup states ({', '.join(SETUP_ITEMS)})", "show")
    section = Section(kind=kind, title=reader.text("title", ""), text=reader.text("text", ""), runs=section_runs,
                      splits=splits, table=reader.optional_integer("table"), names=names, paper=paper,
                      of_table=reader.optional_integer("of_table"), checks=checks, task=reader.text("task", ""),
                      note=reader.text("note", ""), digits=reader.integer("digits", 1, low=0),
                      column=reader.text("column", ""), show=show, describe=reader.flag("describe"),
                      kinds=reader.names("kinds", ()), sentences=tuple(sentences), source=reader.path("source", ""),
                      config=reader.text("config", ""), spread=reader.flag("spread"), seeds=seeds,
                      explain=reader.flag("explain"), earlier=earlier,
                      only=reader.choice("only", ("readme", "document")) if reader.has("only") else "")
    if kind == "headline" and (not section_runs or not splits):
        raise reader.error("a 'headline' section needs its runs and splits", "runs")
    if kind == "headline":
        try:
            unknown = sorted(template_fields(section.text) - headline_fields(section))
        except ValueError as err:
            raise reader.error(f"a template with unbalanced braces ({err})", "text") from None
        if unknown:
            raise reader.error(f"{', '.join('{' + f + '}' for f in unknown)}: no such value (a headline fills in "
                               "{RUN_SPLIT}, {RUN_SPLIT_paper}, {RUN_SPLIT_minus_OTHER} and, with of_table, "
                               "{RUN_SPLIT_minus_OTHER_vs_spread} of its runs and splits)", "text")
    if kind == "editions" and (not section_runs or not splits or not earlier):
        raise reader.error("an 'editions' section needs its runs, splits and earlier editions (LABEL: RECORDS_JSON)",
                           "earlier")
    if kind == "seeds" and (not seeds or section.of_table is None):
        raise reader.error("a 'seeds' section needs seeds (RUN: RUN_OTHER_SEED) and the table it measures (of_table)",
                           "seeds")
    reader.done()
    return section


SPREAD_FIELD = "_vs_spread"  #: suffix of a headline placeholder: a difference held to the seed spread


def difference_field(run: str, split: str, other: str) -> str:
    """The ``headline`` placeholder of ``run``'s ``split`` average less ``other``'s (points)."""
    return f"{run}_{split}_minus_{other}"


def headline_fields(section: Section) -> set[str]:
    """The placeholders a ``headline`` section's text may use: ``{RUN_SPLIT}`` (the run's average, %),
    ``{RUN_SPLIT_paper}`` (the paper's), ``{RUN_SPLIT_minus_OTHER}`` (:func:`difference_field`: the run's average
    less another row's, points) and, with ``of_table``, ``{RUN_SPLIT_minus_OTHER_vs_spread}`` (whether that
    difference exceeds table ``of_table``'s seed spread on the split)."""
    fields = set()
    for run in section.runs:
        for split in section.splits:
            fields |= {f"{run}_{split}", f"{run}_{split}_paper"}
            for other in (r for r in section.runs if r != run):
                fields.add(difference_field(run, split, other))
                if section.of_table is not None:
                    fields.add(difference_field(run, split, other) + SPREAD_FIELD)
    return fields


def template_fields(text: str) -> set[str]:
    """The ``{NAME}`` placeholders of a template (``{{`` and ``}}`` are braces).

    Raises:
        ValueError: unbalanced braces.
    """
    return {name for _, name, _, _ in string.Formatter().parse(text) if name is not None}


def _pairs(reader: _Reader, known: set[str]) -> tuple[tuple[str, str], ...]:
    """An ``exceeds_spread`` check's ``pairs``: a list of two different runs of the spec each."""
    raw = reader.raw("pairs", [])
    if not isinstance(raw, list) or not all(isinstance(p, list) and len(p) == 2 and p[0] != p[1]
                                            and all(isinstance(r, str) and r in known for r in p) for p in raw):
        raise reader.error(f"expected a list of pairs of two different runs of this spec, got {shown(raw)}", "pairs")
    return tuple((a, b) for a, b in raw)


def _check_spread_targets(reader: _Reader, report: ReportSpec) -> None:
    """Every ``exceeds_spread`` check, and every ``headline`` whose differences are held to a seed spread
    (``of_table``), names rows of its table, which has a ``seeds`` section. The table and its ``seeds`` section are
    looked up in the summary and details only (where the report measures the spread: ``seed_spread``), also for a
    check in a README block."""
    parts = {"summary": report.summary, "details": report.details,
             **{f"blocks.{name}": block for name, block in report.blocks.items()}}
    sections = [*report.summary, *report.details]
    for key, part in parts.items():
        held = [(repr(c.text), c.of_table, {r for pair in c.pairs for r in pair}) for section in part
                for c in section.checks if c.kind == SPREAD_CHECK]
        held += [("the headline", s.of_table, set(s.runs)) for s in part if s.kind == "headline" and s.of_table]
        for what, number, runs in held:
            table = next((s for s in sections if s.table == number), None)
            if table is None or not any(s.kind == "seeds" and s.of_table == number for s in sections):
                raise reader.error(f"{what}: table {number} has no seeds section to measure its seed spread", key)
            stray = sorted(runs - set(table.runs))
            if stray:
                raise reader.error(f"{what}: {', '.join(stray)} is no row of table {number}", key)


def _sections(reader: _Reader, key: str, runs: Sequence[str]) -> tuple[Section, ...]:
    raw = reader.raw(key, [])
    if not isinstance(raw, list):
        raise reader.error(f"expected a list of sections, got {shown(raw)}", key)
    return tuple(_section(reader.at(item, f"{key}[{i}]"), runs)
                 for i, item in enumerate(raw))


def _readme_gate(reader: _Reader, report: ReportSpec) -> ReadmeGate | None:
    """``report.readme_when`` (``None`` when absent): ``complete:`` a list of the report's table numbers."""
    if not reader.has("readme_when"):
        return None
    gate = reader.sub("readme_when")
    raw = gate.raw("complete")
    if not isinstance(raw, list) or not raw or not all(isinstance(n, int) and not isinstance(n, bool) for n in raw):
        raise gate.error(f"expected a list of the report's table numbers, got {shown(raw)}", "complete")
    tables = sorted({s.table for s in (*report.summary, *report.details) if s.table is not None})
    unknown = [n for n in raw if n not in tables]
    if unknown:
        raise gate.error(f"{', '.join(map(str, unknown))}: no table of this report (its tables: "
                         f"{', '.join(map(str, tables)) or 'none'})", "complete")
    gate.done()
    if not report.readme and not report.zoo_readme:
        raise reader.error("holds back nothing: it gates the README's blocks (readme) and the zoo's README "
                           "(zoo_readme)", "readme_when")
    return ReadmeGate(complete=tuple(dict.fromkeys(raw)))


def _readme_blocks(reader: _Reader, runs: Sequence[str]) -> dict[str, tuple[Section, ...]]:
    """``report.blocks``: marker name -> the sections of that README block."""
    if not reader.has("blocks"):
        return {}
    sub = reader.sub("blocks")
    out = {}
    for name in list(sub.data):
        if not isinstance(name, str) or not _MARKER.match(name) or name == reader.data.get("block"):
            raise sub.error(f"expected a marker name (lower case, digits, -) other than the block's, got {name!r}",
                            str(name))
        out[name] = _sections(sub, name, runs)
    sub.done()
    return out


# ------------------------------------------------------------------------------------------------ the spec
def spec_path(name: str | Path) -> Path:
    """A spec file: the path itself when it exists, else the built-in spec of that name
    (``paper_tables`` -> ``abm/configs/experiments/paper_tables.yaml``)."""
    return builtin_or_file(name, SPECS, "experiment spec")


def builtin_specs() -> list[str]:
    """Names of the built-in specs."""
    return sorted(p.stem for p in SPECS.glob("*.yaml"))


def load_spec(name: str | Path, *, check_tasks: bool = True) -> ExperimentSpec:
    """Read and validate an experiment spec (a file, or a built-in name; see :func:`spec_path`).

    ``check_tasks=False`` leaves the task names unchecked against the task registry, which imports the
    simulator's task modules (numpy, the asset catalogue): for reading a built-in spec's defaults into a command's
    ``--help``, which must stay light; whatever then runs the spec checks them (``abm data generate --task``).

    Raises:
        SpecError: (a ``ValueError``) naming the file and the key of the first mistake.
        FileNotFoundError: no such file or built-in spec.
    """
    path = spec_path(name)
    try:
        data = load_yaml(path, "experiment spec")
    except ValueError as err:
        raise SpecError(str(err)) from None
    return parse_spec(data, path, check_tasks=check_tasks)


def parse_spec(data: Any, path: Path, *, check_tasks: bool = True) -> ExperimentSpec:
    """The :class:`ExperimentSpec` of the plain data ``data`` read from ``path`` (see :func:`load_spec`)."""
    _tasks = functools.partial(_task_names, check=check_tasks)
    top = _Reader(data, path)
    name = top.text("name")
    if not _NAME.match(name):
        raise top.error(f"expected a plain name (letters, digits, _ . -), got {name!r}", "name")
    lists: dict[str, tuple[str, ...]] = {}
    task_lists = top.sub("tasks")
    for key in list(task_lists.data):
        lists[key] = task_lists.names(key)

    d = top.sub("data")
    generate = "data generate"
    data_spec = DataSpec(tasks=_tasks(d, "tasks", lists, trainable=True), split=d.choice("split", SPLITS, "seen"),
                         episodes=d.flag_value("episodes", 20, generate, "episodes"),
                         workers=d.flag_value("workers", WORKERS, generate, "workers"),
                         seed=d.flag_value("seed", 0, generate, "seed"),
                         resolution=d.flag_value("resolution", CAMERA_RESOLUTION, generate, "resolution"),
                         folder=d.path("folder", "", folder=True) or None)
    d.done()

    t = top.sub("training")
    training = TrainingSpec(recipe=t.path("recipe", None),
                            tasks=_tasks(t, "tasks", lists, trainable=True) if t.has("tasks") else None,
                            steps=t.optional_integer("steps"))
    recipe = _recipe(t, training.recipe)
    common = {**_checked(t, "train", TrainConfig, ENGINE_TRAIN_FIELDS + ("tasks", "steps")),
              **({"steps": training.steps} if training.steps is not None else {}),
              **({"tasks": list(training.tasks)} if training.tasks else {})}
    common_policy = {**(recipe.pop("policy", None) or {}), **_checked(t, "policy", PolicyConfig, POLICY_FIXED)}
    t.done()

    clip = top.path("clip", "", folder=True)
    runs: dict[str, RunSpec] = {}
    r = top.sub("runs")
    if not r.data:
        raise r.error("is required: at least one run")
    for run_name in list(r.data):
        if not isinstance(run_name, str) or not _NAME.match(run_name) or "@" in run_name:
            raise r.error(f"expected a plain run name (letters, digits, _ . -), got {run_name!r}")
        one = r.sub(run_name)
        train = {**common, **_checked(one, "train", TrainConfig, ENGINE_TRAIN_FIELDS + ("tasks", "steps"))}
        if "method" not in train:
            raise one.error("needs a method (train: {method: abm|rvt|ifd|...})", "train")
        policy = {**common_policy, **_checked(one, "policy", PolicyConfig, POLICY_FIXED)}
        try:
            config = TrainConfig.from_recipe({**recipe, **train, "policy": policy})
            config = config.with_clip(clip) if clip and needs_clip(config) else config
        except ValueError as err:
            raise SpecError(f"{path}: runs.{run_name} (the recipe {training.recipe} with the spec's overrides): "
                            f"{err}") from None
        runs[run_name] = RunSpec(name=run_name, label=one.text("label", run_name),
                                 grounding=one.text("grounding", config.grounder.kind), config=config,
                                 caveat=one.text("caveat", ""))
        one.done()
    r.used |= set(r.data)
    names = list(runs)

    e = top.sub("evaluation")
    splits = []
    s = e.sub("splits")
    for split in list(s.data):
        if split not in SPLITS:
            raise s.error(f"{split!r} is no object split ({', '.join(SPLITS)})")
        one = s.sub(split)
        split_runs = one.names("runs") if one.has("runs") else None
        splits.append(EvalSplit(split=split, tasks=_tasks(one, "tasks", lists), runs=split_runs))
        one.done()
    variants = []
    v = e.sub("variants")
    for variant in list(v.data):
        one = v.sub(variant)
        base = one.text("run")
        if base not in runs:
            raise one.error(f"{base!r} is no run of this spec (known: {', '.join(names)})", "run")
        expert = one.choice("expert_keyframes", EXPERT_KEYFRAME_KINDS) if one.has("expert_keyframes") else ""
        grounder = one.choice("grounder", GROUNDERS.names()) if one.has("grounder") or not expert else ""
        if not expert and variant != f"{base}@{grounder}":
            raise v.error(f"a variant is named RUN@GROUNDER ({base}@{grounder}), got {variant!r}")
        if expert and (not _NAME.match(variant) or variant in runs):
            raise v.error(f"an expert-keyframe arm needs a plain name that is no run's, got {variant!r}")
        variants.append(GrounderVariant(name=variant, run=base, grounder=grounder, label=one.text("label", variant),
                                        description=one.text("description", ""), expert_keyframes=expert))
        one.done()
    evaluation = EvaluationSpec(episodes=e.flag_value("episodes", 25, "eval", "episodes"),
                                repeats=e.flag_value("repeats", 1, "eval", "repeats"),
                                workers=e.flag_value("workers", WORKERS, "eval", "workers"),
                                max_steps=e.flag_value("max_steps", MAX_KEYFRAMES, "eval", "max_steps"),
                                gifs=e.flag_value("gifs", 0, "eval", "gifs"), from_zoo=e.flag("from_zoo"),
                                splits=tuple(splits), variants=tuple(variants), zoo_eval=e.names("zoo_eval", ()),
                                device=e.flag_value("device", "cpu", "eval", "device"))
    e.done()
    evaluated = set(names) | {v.name for v in variants}
    for one_split in evaluation.splits:
        for run in one_split.runs or ():
            if run not in evaluated:
                raise e.error(f"{run!r} is no run or variant of this spec", f"splits.{one_split.split}.runs")
    for run in evaluation.zoo_eval:
        if run not in runs:
            raise e.error(f"{run!r} is no run of this spec", "zoo_eval")

    diagnose = None
    if top.has("diagnose"):
        g = top.sub("diagnose")
        diagnose = DiagnoseSpec(episodes=g.integer("episodes", 5), splits=g.names("splits", ("seen", "unseen")),
                                tasks=g.tasks("tasks", lists) if g.has("tasks") else None,
                                oracle_mask=g.flag("oracle_mask"),
                                steps=tuple(_steps(g)), kinds=g.names("kinds", ()),
                                skill_text=_skill_text(g, runs),
                                destination_grounding=_destination_grounding(g, lists, _tasks))
        g.done()

    res = top.sub("resources")
    resources = Resources(trainings_at_a_time=res.integer("trainings_at_a_time", 2, high=256),
                          threads_each=res.integer("threads_each", 1, high=256),  # as abm experiment run --threads
                          order=res.names("order", ()))
    for run in resources.order:
        if run not in runs:
            raise res.error(f"{run!r} is no run of this spec", "order")
    res.done()

    rep = top.sub("report")
    figures = []
    raw_figures = rep.raw("figures", [])
    if not isinstance(raw_figures, list):
        raise rep.error(f"expected a list of figures, got {shown(raw_figures)}", "figures")
    for i, item in enumerate(raw_figures):
        f = rep.at(item, f"figures[{i}]")
        file = f.path("file", None)
        if not file.endswith(".png"):
            raise f.error(f"expected a PNG file (NAME.png), got {file!r}", "file")
        figures.append(FigureSpec(kind=f.choice("kind", FIGURE_KINDS), file=file, alt=f.text("alt"),
                                  runs=f.names("runs", ())))
        f.done()
    rows = [*names, *(v.name for v in variants)]
    report = ReportSpec(title=rep.text("title", ""), document=rep.path("document", ""),
                        records=rep.path("records", ""), readme=rep.path("readme", ""), block=rep.text("block", ""),
                        arm_records=rep.path("arm_records", ""),
                        summary=_sections(rep, "summary", rows), details=_sections(rep, "details", rows),
                        blocks=_readme_blocks(rep, rows),
                        figures=tuple(figures), zoo_readme=rep.flag("zoo_readme"), zoo_note=rep.text("zoo_note", ""))
    report = replace(report, readme_when=_readme_gate(rep, report))
    if report.readme and not _MARKER.match(report.block):
        raise rep.error(f"a README block needs a marker name (lower case, digits, -), got {report.block!r}", "block")
    if report.blocks and not report.readme:
        raise rep.error("further README blocks need the README they go into (readme)", "blocks")
    if not report.document and not report.readme:
        raise rep.error("writes nothing: give a document, a README block, or both", "document")
    if report.document and not report.title:
        raise rep.error("a document needs a title", "title")
    rep.done()

    spec = ExperimentSpec(
        name=name, path=path, about=top.text("about", ""), out=top.path("out", f"runs/{name}", folder=True),
        kept=top.path("kept", f"docs/results/{name}", folder=True), data=data_spec, training=training, runs=runs,
        evaluation=evaluation, report=report, zoo=top.path("zoo", "", folder=True),
        carry=top.path("carry", "", folder=True), clip=clip,
        clip_command=top.text("clip_command", ""), diagnose=diagnose,
        resources=resources, zoo_suffix=top.text("zoo_suffix", ""), edition=top.integer("edition", 1),
        finished=top.text("finished", ""))
    top.done()
    if spec.finished and spec.carry:
        raise top.error("a finished experiment carries nothing: remove its carry", "carry")
    if spec.zoo_suffix and not _NAME.match("x" + spec.zoo_suffix):
        raise top.error(f"expected letters, digits, _ . - (e.g. _v2), got {spec.zoo_suffix!r}", "zoo_suffix")
    if spec.edition > 1 and not spec.zoo_suffix:
        raise top.error("a later edition needs a zoo_suffix, so its models do not replace the first edition's",
                        "zoo_suffix")
    if spec.zoo_suffix and not spec.zoo:
        raise top.error("a zoo_suffix needs a zoo folder to export into", "zoo")
    if any(run.needs_clip for run in runs.values()) and not spec.clip:
        raise top.error("runs need the benchmark CLIP (grounder or language clip): give its folder", "clip")
    if diagnose is not None and diagnose.destination_grounding is not None and not spec.clip:
        raise top.error("diagnose.destination_grounding measures the spec's CLIP grounder: give its folder", "clip")
    _check_spread_targets(rep, report)
    if evaluation.from_zoo and not spec.zoo:
        raise top.error("evaluation.from_zoo needs a zoo folder to export into", "zoo")
    if report.zoo_readme and not spec.zoo:
        raise top.error("report.zoo_readme needs a zoo folder", "zoo")
    return spec


@functools.cache
def command_parser(command: str) -> argparse.ArgumentParser:
    """The parser of ``abm COMMAND`` (``data generate``, ``eval``, ``train``): a spec's values pass the checks
    of the flags the engine hands them to."""
    import importlib

    parser = argparse.ArgumentParser(prog="abm")
    module = {"data": "abm.cli.data", "eval": "abm.cli.evaluate", "train": "abm.cli.train"}[command.split()[0]]
    importlib.import_module(module).register(parser.add_subparsers())  # only this command's options
    for word in command.split():
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[word]
    return parser


def _task_names(reader: _Reader, key: str, lists: Mapping[str, tuple[str, ...]], trainable: bool = False,
                check: bool = True) -> tuple[str, ...]:
    """A list of task names (or a task list's name), each a task of the benchmark (``trainable``: one
    demonstrations can be generated for, as ``abm data generate --task`` checks; ``check=False``: not looked up
    in the registry, see :func:`load_spec`)."""
    names = reader.tasks(key, lists)
    if not check:
        return names
    from abm.sim.tasks import TASKS  # the task registry (no simulator is built)

    for task in names:
        if task not in TASKS:
            raise reader.error(f"{task!r} is no task of the benchmark (known: {', '.join(sorted(TASKS))})", key)
        if trainable and TASKS[task].evaluation_only:
            raise reader.error(f"{task!r} is an evaluation-only task: no demonstrations exist for it", key)
    return names


def _skill_text(reader: _Reader, runs: Mapping[str, RunSpec]) -> SkillTextSpec | None:
    """The diagnosis' ``skill_text`` block (``None`` when absent)."""
    if not reader.has("skill_text"):
        return None
    s = reader.sub("skill_text")
    readers = [n for n, r in runs.items() if VARIANTS[r.method].language == "skill"]
    named = s.names("runs", readers)
    for run in named:
        if run not in readers:
            raise s.error(f"{run!r} is no run of this spec that reads a skill text (those: {', '.join(readers)})",
                          "runs")
    within = s.number("within_cm", 5.0)
    if within <= 0:
        raise s.error(f"expected a distance > 0 cm, got {within:g}", "within_cm")
    probe = SkillTextSpec(tasks=s.names("tasks"), kind=s.text("kind", "move"), episodes=s.integer("episodes", 5),
                          split=s.choice("split", SPLITS, "seen"), runs=named, within_cm=within)
    s.done()
    return probe


def _destination_grounding(reader: _Reader, lists: Mapping[str, tuple[str, ...]],
                           task_names: Callable[..., tuple[str, ...]]) -> DestinationGroundingSpec | None:
    """The diagnosis' ``destination_grounding`` block (``None`` when absent)."""
    if not reader.has("destination_grounding"):
        return None
    d = reader.sub("destination_grounding")
    splits = d.names("splits", ("seen", "unseen"))
    for split in splits:
        if split not in SPLITS:
            raise d.error(f"{split!r} is no object split ({', '.join(SPLITS)})", "splits")
    found = DestinationGroundingSpec(episodes=d.integer("episodes", 5), splits=splits,
                                     tasks=task_names(d, "tasks", lists) if d.has("tasks") else None)
    d.done()
    return found


def _steps(reader: _Reader) -> list[int]:
    value = reader.raw("steps", [])
    if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0
                                              for v in value):
        raise reader.error(f"expected a list of positive step numbers, got {shown(value)}", "steps")
    return list(value)
