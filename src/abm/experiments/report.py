"""Every generated block of an experiment, from its spec and its outcomes (never typed by hand).

:func:`write_report` reads the outcomes of an experiment (OUT after :func:`abm.experiments.state.restore`, so
the committed ones count) and writes

* the document (``report.document``, e.g. ``docs/results/paper_tables.md``): the summary sections, then the
  detail sections;
* the README block between ``<!-- BLOCK:start -->`` and ``<!-- BLOCK:end -->`` (the summary sections and a
  link to the document), and the further blocks of ``report.blocks`` in the same README (e.g. a headline);
* the records (``report.records``, e.g. ``docs/results/paper_tables.json``): one record per (table, run,
  task, split) cell with ``successes`` and ``episodes`` (plus mean, std and per-repeat rates);
* the zoo's index and README (``ZOO/index.json``, ``ZOO/README.md``) when the spec exports into a zoo:
  every exported model (method, grounding, recipe, data, steps, minutes, size, sha256) and the benchmark CLIP;
  the entries other specs exported into the same zoo (an earlier or later edition's) are kept as they are, and
  the zoo's README is written by the newest edition's spec;
* the run summaries (``KEPT/runs.json``) of an experiment without a zoo, every run's compact loss curve
  (``KEPT/training_RUN.csv``, also kept when a run is exported), and the figures (``report.figures``), drawn from
  the kept files only.

A report is a list of paragraphs (blocks) joined by blank lines; each section of the spec
(:data:`abm.experiments.spec.SECTION_KEYS`) adds zero or more; a section marked ``only: document`` (or
``readme``) is left out of the other. Cells not evaluated yet show "–", so tables fill in stages (the first line
says so while one does). Links in the summary are written relative to the repository root (the README's folder) and
rewritten relative to the document's folder in the document.
"""

from __future__ import annotations

import csv
import json
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from abm.errors import ConfigError, DataError, OutputError
from abm.experiments.arm_records import Loops, arm_records, is_arm_records, loop_counts, loop_share
from abm.experiments.spec import SPECS, ExperimentSpec, GrounderVariant, Section, TargetCheck
from abm.experiments.state import Layout, machines, stage_minutes
from abm.files import is_inside, sha256_file
from abm.zoo import edition

Rate = Mapping[str, Any]  #: one evaluation cell (a record of ``abm eval``'s results.json)
Cells = dict[tuple[str, str, str], dict[str, Any]]  #: (run, task, split) -> its rate
LOSS_COLUMNS = ("step", "total", "translation", "rotation", "gripper", "zoom_translation")
STAGE_ORDER = ("data", "ground", "train", "export", "eval", "diagnose")
_WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")
_LINK = re.compile(r"\]\(([^)\s]+)\)")


@dataclass
class Outcomes:
    """What the report is written from.

    Attributes:
        cells: every evaluated cell, keyed by (run or variant, task, split).
        summaries: keyframe-accuracy summary rows per diagnosis name (``RUN``, ``RUN@oracle``), in spec order.
        entries: the trained runs' summaries (the spec's entries of the zoo index and the benchmark CLIP's, or
            ``KEPT/runs.json``), in spec order.
        stages: minutes per stage, every session added up.
        machines: every machine that ran a stage.
        zoo_eval: the timed ``abm zoo eval``: its table and seconds, or ``None`` before it ran.
        probes: the skill-text probes (``benchmarks/skill_text_probe.py``'s JSON) by (run, task).
        index: the whole zoo index the report writes (with other specs' entries), or ``None`` without a zoo.
        loops: grasp <-> lift loops per (run or variant, task, split): (episodes that loop, episodes)
            (:func:`abm.experiments.arm_records.loop_counts`).
    """

    cells: Cells
    summaries: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    entries: list[dict[str, Any]] = field(default_factory=list)
    stages: dict[str, float] = field(default_factory=dict)
    machines: list[str] = field(default_factory=list)
    zoo_eval: tuple[str, int] | None = None
    probes: dict[tuple[str, str], dict[str, Any]] = field(default_factory=dict)
    index: list[dict[str, Any]] | None = None
    loops: Loops = field(default_factory=dict)


# -------------------------------------------------------------------------------------------------- reading
def collect_cells(spec: ExperimentSpec, layout: Layout) -> Cells:
    """``(run, task, split) -> rate`` from every evaluation JSON of the spec's runs and variants under OUT."""
    cells: Cells = {}
    for name in [*spec.runs, *(v.name for v in spec.evaluation.variants)]:
        for split in spec.evaluation.splits:
            path = layout.eval_dir(name, split.split) / "results.json"
            if path.is_file():
                for rate in json.loads(path.read_text()):
                    cells[(name, rate["task"], rate["split"])] = rate
    return cells


def keyframe_summaries(spec: ExperimentSpec, layout: Layout) -> dict[str, list[dict[str, Any]]]:
    """Diagnosis name -> its summary rows (``OUT/keyframe_accuracy/NAME.json``), in spec order."""
    found = {}
    for name in spec.diagnoses():
        path = layout.diagnosis(name)
        if path.is_file():
            found[name] = json.loads(path.read_text())["summary"]
    return found


def skill_text_probes(spec: ExperimentSpec, layout: Layout) -> dict[tuple[str, str], dict[str, Any]]:
    """``(run, task) -> the probe's JSON`` of every skill-text probe of the diagnosis that ran."""
    found = {}
    for run, task in spec.probes():
        path = layout.skill_text(run, task)
        if path.is_file():
            found[(run, task)] = json.loads(path.read_text())
    return found


def training_summary(run_dir: Path) -> dict[str, float] | None:
    """Steps, minutes and mean samples/s of a run folder's log (``None`` before its first row)."""
    log = run_dir / "log.csv"
    if not log.is_file():
        return None
    with log.open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    last = rows[-1]
    sps = [float(r["samples_per_s"]) for r in rows[1:]] or [float(last["samples_per_s"])]
    return {"steps": int(last["step"]), "elapsed_min": float(last["elapsed_s"]) / 60,
            "samples_per_s": sum(sps) / len(sps)}


def minutes_at_steps(run_dir: Path, steps: Sequence[int]) -> dict[str, float]:
    """Training minutes when the run's log reached each of ``steps`` (``{"1000": 25.3}``)."""
    log = run_dir / "log.csv"
    if not steps or not log.is_file():
        return {}
    with log.open() as f:
        at = {int(r["step"]): float(r["elapsed_s"]) / 60 for r in csv.DictReader(f)}
    return {str(s): round(at[s], 1) for s in steps if s in at}


def describe_run(run_dir: Path) -> dict[str, Any]:
    """What only a run folder knows (``config.json``, ``log.csv``): tasks, data, steps, recipe, language,
    grounder and training minutes; ``{}`` when the folder is gone (a fresh clone)."""
    cfg_path = run_dir / "config.json"
    if not cfg_path.is_file():
        return {}
    cfg = json.loads(cfg_path.read_text())
    train = cfg["train"]
    entry: dict[str, Any] = {
        "tasks": train["tasks"], "data": str(train["data"]), "steps": train["steps"],
        "recipe": {k: train[k] for k in ("batch", "optimizer", "warmup", "weight_decay", "seed")}
        | {"lr": cfg["lr"], "resolution": cfg["policy"]["resolution"], "patch_size": cfg["policy"]["patch_size"],
           "preset": cfg["policy"]["preset"]},
        "language": cfg["language"].get("kind"), "grounder_spec": cfg["grounder"],
    }
    if cfg["policy"].get("workspace_size", 1.0) != 1.0:  # not the default 1 m cube: say so
        entry["recipe"]["workspace_size"] = cfg["policy"]["workspace_size"]
    if cfg["policy"].get("rotation_crop"):  # the rotation head also reads a crop (PolicyConfig.rotation_crop)
        entry["recipe"]["rotation_crop"] = cfg["policy"]["rotation_crop"]
    if cfg["policy"].get("zoom_size"):  # a zoomed second stage (PolicyConfig.zoom_size)
        entry["recipe"] |= {k: cfg["policy"][k] for k in ("zoom_size", "zoom_resolution", "zoom_patch_size")}
    trained = training_summary(run_dir)
    if trained is not None:
        entry["train_minutes"] = round(trained["elapsed_min"], 1)
    return entry


def zoo_index(spec: ExperimentSpec, layout: Layout) -> list[dict[str, Any]]:
    """Every exported model of the spec (and the benchmark CLIP) as the zoo index describes it, with the
    entries other specs exported into the same zoo (another edition's: other names) kept as they are.

    A model's entry keeps what the index knew (on a fresh clone the run folder is gone) and is refreshed from
    its run folder when that is here; the file's size and sha256 are read anew. A later edition's entries
    also record their ``edition``, ``experiment``, ``run`` and whether ``abm zoo eval`` compares them
    (``compared``: the spec's ``evaluation.zoo_eval``; :func:`abm.zoo.pick`). Order: the index's, with the
    spec's models together in the spec's order where its first one stood (at the end when new), the
    benchmark CLIP last."""
    assert layout.zoo is not None
    index_path = layout.zoo / "index.json"
    listed = json.loads(index_path.read_text()) if index_path.is_file() else []
    known = {e["name"]: e for e in listed}
    mine = {spec.zoo_name(name) for name in spec.runs}
    entries = []
    for name, run in spec.runs.items():
        file = layout.zoo_file(name)
        if not file.is_file():
            continue
        entry = dict(known.get(spec.zoo_name(name), {}))
        entry.update({"name": spec.zoo_name(name), "file": file.name, "label": run.label, "method": run.method,
                      "grounder": run.grounding, "tables": spec.tables_of(name), "size_bytes": file.stat().st_size,
                      "sha256": sha256_file(file)})
        if spec.edition > 1 or spec.zoo_suffix:
            entry.update({"edition": spec.edition, "experiment": spec.name, "run": name,
                          "compared": name in spec.evaluation.zoo_eval})
        entry.update(describe_run(layout.run_dir(name)))
        entries.append(entry)
    ordered: list[dict[str, Any]] = []
    placed = False
    for other in listed:
        if other.get("name") in mine:
            ordered += [] if placed else entries
            placed = True
        elif other.get("name") != "benchmark-clip" and (layout.zoo / str(other.get("file", other["name"]))).is_file():
            ordered.append(other)  # another spec's model (another edition): kept as it is
    entries = ordered if placed else ordered + entries
    clip = layout.clip
    if clip is not None and (clip / "model.safetensors").is_file():
        meta = json.loads((clip / "abm_clip.json").read_text()) if (clip / "abm_clip.json").is_file() else {}
        entries.append({"name": "benchmark-clip", "file": clip.name + "/", "method": "clip",
                        "size_bytes": (clip / "model.safetensors").stat().st_size,
                        "sha256": sha256_file(clip / "model.safetensors"),
                        "recipe": meta.get("recipe"), "steps": meta.get("steps"),
                        "train_minutes": round(meta["train_seconds"] / 60, 1) if "train_seconds" in meta else None,
                        "zero_shot_top1": (meta.get("zero_shot") or {}).get("accuracy"),
                        "command": spec.clip_command or None})
    return entries


def kept_run_summaries(spec: ExperimentSpec, layout: Layout) -> list[dict[str, Any]]:
    """The runs' summaries of an experiment without a zoo: ``KEPT/runs.json`` refreshed from the run folders
    that are here (with ``samples_per_s``)."""
    path = layout.kept / "runs.json"
    known = {e["name"]: e for e in json.loads(path.read_text())} if path.is_file() else {}
    entries = []
    for name, run in spec.runs.items():
        entry = dict(known.get(name, {}))
        fresh = describe_run(layout.run_dir(name))
        trained = training_summary(layout.run_dir(name))
        if fresh:
            entry.update({"name": name, "label": run.label, "method": run.method, "grounder": run.grounding})
            entry.update(fresh)
            if trained is not None:
                entry["samples_per_s"] = round(trained["samples_per_s"], 2)
            steps = spec.diagnose.steps if spec.diagnose else ()
            at = minutes_at_steps(layout.run_dir(name), steps)
            if at:
                entry["minutes_at_steps"] = at
        if entry:
            entries.append(entry)
    return entries


def collect(spec: ExperimentSpec, layout: Layout) -> Outcomes:
    """Every outcome the report is written from (OUT after the committed ones were restored into it)."""
    zoo_eval = None
    folder = layout.zoo_eval
    if (folder / "results.md").is_file() and (folder / "seconds").is_file():
        zoo_eval = ((folder / "results.md").read_text().strip(), int((folder / "seconds").read_text()))
    index = zoo_index(spec, layout) if layout.zoo is not None else None
    mine = {spec.zoo_name(name) for name in spec.runs} | {"benchmark-clip"}
    entries = [e for e in index if e["name"] in mine] if index is not None else kept_run_summaries(spec, layout)
    return Outcomes(cells=collect_cells(spec, layout), summaries=keyframe_summaries(spec, layout), entries=entries,
                    stages=stage_minutes(layout.times), machines=machines(layout.machines), zoo_eval=zoo_eval,
                    probes=skill_text_probes(spec, layout), index=index,
                    loops=loop_counts(spec, layout) if _reads_loops(spec) else {})


def _reads_loops(spec: ExperimentSpec) -> bool:
    """Whether the report shows grasp <-> lift loops (its arm records, a ``loops`` section or check), which are
    read from every evaluation's outcome archive."""
    sections = (*spec.report.summary, *spec.report.details)
    return bool(spec.report.arm_records) or any(
        s.kind == "loops" or any(c.kind == "loops" for c in s.checks) for s in sections)


# ---------------------------------------------------------------------------------------------- numbers
def successes(rate: Rate) -> int:
    """Successful episodes of a cell."""
    return round(float(rate["mean"]) * int(rate["episodes"]) / 100)


def cell(rate: Rate | None) -> str:
    """``mean ± std (successes/episodes)`` (no ± for one repeat), or "–" when not evaluated."""
    if rate is None:
        return "–"
    std = f" ± {rate['std']:.0f}" if len(rate["per_repeat"]) > 1 else ""
    return f"{rate['mean']:.0f}{std} ({successes(rate)}/{rate['episodes']})"


def average(cells: Cells, run: str, split: str, tasks: Sequence[str]) -> float | None:
    """Mean success over ``tasks``, or ``None`` until every task of the split is evaluated."""
    rates = [cells.get((run, t, split)) for t in tasks]
    if not rates or any(r is None for r in rates):
        return None
    return sum(float(r["mean"]) for r in rates if r is not None) / len(rates)


def standard_error(cells: Cells, run: str, split: str, tasks: Sequence[str]) -> float | None:
    """The standard error of :func:`average` over the repeats: the sample standard deviation (n − 1) of the
    repeat-wise average over ``tasks`` (repeat r: the mean over the tasks of each task's success in repeat r),
    divided by √repeats. ``None`` until every task has the same two or more repeats."""
    rates = [cells.get((run, t, split)) for t in tasks]
    if not rates or any(r is None for r in rates):
        return None
    per_task = [list(r["per_repeat"]) for r in rates if r is not None]
    repeats = len(per_task[0])
    if repeats < 2 or any(len(p) != repeats for p in per_task):
        return None
    by_repeat = np.mean(np.array(per_task, dtype=np.float64), axis=0)
    return float(np.std(by_repeat, ddof=1) / np.sqrt(repeats))


def spread_note(repeats: int) -> str:
    """The sentence under a table whose averages show their standard error."""
    return (f"± in a cell: the standard deviation of the task's success over the {_number(repeats)} repeats; ± "
            f"after an average: its standard error, the sample standard deviation over the repeats of the "
            f"repeat-wise average over the tasks, divided by √{repeats}.")


def pct(v: float | None, digits: int = 1) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def ratio(seen: float | None, unseen: float | None) -> str:
    return "–" if seen is None or unseen is None or seen <= 0 else f"{unseen / seen:.2f}"


def _number(n: int) -> str:
    return _WORDS[n] if 0 <= n < len(_WORDS) else str(n)


def _row(values: Sequence[str]) -> str:
    return "| " + " | ".join(values) + " |"


def _head(values: Sequence[str]) -> list[str]:
    return [_row(values), "|---" * len(values) + "|"]


# --------------------------------------------------------------------------------------------- sections
@dataclass
class Context:
    """What every section writer sees: the spec, its outcomes and the split -> tasks map."""

    spec: ExperimentSpec
    outcomes: Outcomes
    layout: Layout

    @property
    def cells(self) -> Cells:
        return self.outcomes.cells

    def tasks(self, split: str) -> tuple[str, ...]:
        return self.spec.split_tasks().get(split, ())

    def average(self, run: str, split: str) -> float | None:
        return average(self.cells, run, split, self.tasks(split))

    def error_shown(self, run: str, split: str, spread: bool, digits: int = 1) -> str:
        """`` ± standard error`` of an average (:func:`standard_error`) when ``spread`` and it is known, else ""."""
        se = standard_error(self.cells, run, split, self.tasks(split)) if spread else None
        return f" ± {se:.{digits}f}" if se is not None else ""

    def average_shown(self, run: str, split: str, spread: bool, digits: int = 1) -> str:
        """The average as a table shows it: with its standard error when ``spread`` (:meth:`error_shown`)."""
        return pct(self.average(run, split), digits) + self.error_shown(run, split, spread, digits)

    def repeats(self, runs: Sequence[str], splits: Sequence[str]) -> int:
        """The most repeats of any evaluated cell of these runs and splits (0: none evaluated)."""
        return max((len(r["per_repeat"]) for (run, _, split), r in self.cells.items()
                    if run in runs and split in splits), default=0)

    def spread_note(self, section: Section) -> list[str]:
        """:func:`spread_note` under a ``spread`` table once its cells have two or more repeats."""
        repeats = self.repeats(section.runs, section.splits)
        return [spread_note(repeats)] if section.spread and repeats > 1 else []

    def label(self, run: str) -> str:
        if run in self.spec.runs:
            return self.spec.runs[run].label
        return next((v.label for v in self.spec.evaluation.variants if v.name == run), run)

    def variant(self, name: str) -> GrounderVariant | None:
        return next((v for v in self.spec.evaluation.variants if v.name == name), None)

    def method(self, name: str) -> str:
        variant = self.variant(name)
        return self.spec.runs[variant.run if variant else name].method

    def describe(self, name: str) -> str:
        variant = self.variant(name)
        return variant.description if variant else self.spec.runs[name].grounding

    def task_order(self) -> dict[str, int]:
        first = self.spec.training.tasks or self.spec.data.tasks
        return {t: i for i, t in enumerate(first)}


DEFAULT_SETUP = ("machines", "recipe", "minutes", "stages", "evaluation")


def _clip_sentence(ctx: Context) -> str:
    clip = ctx.layout.clip
    if clip is None:
        return ""
    meta_path = clip / "abm_clip.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    arch = (meta.get("recipe") or {}).get("arch", {}).get("vision", {})
    size = (f"a {arch.get('num_hidden_layers')}-layer, {arch.get('hidden_size')}-wide ViT at {arch.get('image_size')}² "
            if arch else "")
    return (f"CLIP: the benchmark CLIP in `{ctx.layout.show(clip)}` (`abm clip train`: {size}trained on simulator "
            "renders of every catalog object with their names, never on demonstrations; see docs/grounding.md).")


def _setup(ctx: Context, section: Section) -> list[str]:
    """One paragraph: the machines, data, CLIP, recipe, training minutes and speed, stage times and the
    evaluation protocol (``section.show`` picks and orders them)."""
    spec, out = ctx.spec, ctx.outcomes
    trained = [e for e in out.entries if e.get("method") != "clip"]
    recipe = next((e["recipe"] for e in trained if e.get("recipe")), None)
    parts: dict[str, str] = {}
    if out.machines:
        parts["machines"] = (f"Machine{'s' if len(out.machines) > 1 else ''} (every session that ran a stage): "
                             f"{'; '.join(out.machines)}.")
    d = spec.data
    parts["data"] = f"Data: {d.episodes} {d.split} demonstrations per task ({', '.join(d.tasks)})."
    parts["clip"] = _clip_sentence(ctx)
    if recipe:
        n, t = spec.resources.trainings_at_a_time, spec.resources.threads_each
        side = (f"{_number(n)} trainings at a time with {_number(t)} thread{'s' if t != 1 else ''} each" if n > 1
                else f"one training at a time with {_number(t)} thread{'s' if t != 1 else ''}")
        cube = f" over a {recipe['workspace_size']:g} m cube" if "workspace_size" in recipe else ""
        crop = f", a {recipe['rotation_crop']}-pixel rotation crop" if recipe.get("rotation_crop") else ""
        zoom = (f", a zoomed second stage ({recipe['zoom_resolution']}² views of a {recipe['zoom_size']:g} m cube "
                f"around the first stage's point, patch {recipe['zoom_patch_size']})" if recipe.get("zoom_size")
                else "")
        parts["recipe"] = (f"Recipe (every model): `{recipe['preset']}` preset at {recipe['resolution']}² views{cube}, "
                           f"patch {recipe['patch_size']}{zoom}{crop}, {trained[0].get('steps')} steps of batch "
                           f"{recipe['batch']}, "
                           f"{recipe['optimizer']} lr {recipe['lr']:g}, {side}.")
    if trained:
        parts["minutes"] = "Training minutes: " + ", ".join(
            f"{e.get('run', e['name'])} {e.get('train_minutes', '?')}" for e in trained) + "."
        speeds = [f"{e.get('run', e['name'])} {e['samples_per_s']:.1f}" for e in trained if e.get("samples_per_s")]
        if speeds:
            parts["speed"] = "Training samples/s: " + ", ".join(speeds) + "."
    if out.stages:
        ranked = sorted(out.stages.items(),
                        key=lambda kv: STAGE_ORDER.index(kv[0]) if kv[0] in STAGE_ORDER else len(STAGE_ORDER))
        parts["stages"] = ("Wall time per stage, every session added up (min): "
                           + ", ".join(f"{k} {v:.0f}" for k, v in ranked) + ".")
    n = max((r["episodes"] for r in ctx.cells.values()), default=0)
    reps = max((len(r["per_repeat"]) for r in ctx.cells.values()), default=0)
    show = section.show or DEFAULT_SETUP
    if n:
        where = ", evaluated from the zoo files" if spec.evaluation.from_zoo else ""
        keyframes = f", at most {spec.evaluation.max_steps} keyframes" if "keyframes" in show else ""
        parts["evaluation"] = (f"Evaluation: {n // max(reps, 1)} seeded episodes × {reps} repeats per task and "
                               f"split{keyframes}, the same scenes for every model{where}.")
    setup = [parts[item] for item in show if parts.get(item)]
    return [" ".join(setup)] if setup else []


def _paper(section: Section, run: str, count: int) -> list[str]:
    values = section.paper.get(run)
    return [f"{v}" for v in values] if values else [""] * count


def _per_task(ctx: Context, section: Section) -> list[str]:
    """Rows: the tasks of the first split; columns: every run × split; then averages, unseen / seen and the
    paper's averages."""
    runs, splits = section.runs, section.splits
    head = [section.column or "task"] + [f"{ctx.label(r)} {s}" for r in runs for s in splits]
    lines = _head(head)
    for t in ctx.tasks(splits[0]):
        lines.append(_row([t] + [cell(ctx.cells.get((r, t, s))) for r in runs for s in splits]))
    avg = [[ctx.average(r, s) for s in splits] for r in runs]
    lines.append("| **average** | " + " | ".join(f"**{pct(avg[i][j])}**" + ctx.error_shown(r, s, section.spread)
                                                  for i, r in enumerate(runs) for j, s in enumerate(splits)) + " |")
    if tuple(splits) == ("seen", "unseen"):
        lines.append("| unseen / seen | " + " | ".join(x for pair in avg for x in ("", ratio(*pair))) + " |")
    if section.paper:
        lines.append("| paper average | " + " | ".join(x for r in runs for x in _paper(section, r, len(splits)))
                     + " |")
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(section)


def _per_run(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs; columns: the tasks of one split, the average and the paper's."""
    split = section.splits[0]
    tasks = ctx.tasks(split)
    head = [section.column or "method", *tasks, "average"] + (["paper average"] if section.paper else [])
    lines = _head(head)
    for r in section.runs:
        row = [ctx.label(r)] + [cell(ctx.cells.get((r, t, split))) for t in tasks]
        row.append(ctx.average_shown(r, split, section.spread, section.digits))
        if section.paper:
            row += _paper(section, r, 1)
        lines.append(_row(row))
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(section)


def _averages(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs; columns: seen and unseen averages, their ratio and the paper's."""
    head = [section.column or "run", "seen avg", "unseen avg", "unseen / seen"]
    head += ["paper seen", "paper unseen"] if section.paper else []
    lines = _head(head)
    for r in section.runs:
        seen, unseen = ctx.average(r, "seen"), ctx.average(r, "unseen")
        row = [section.names.get(r, r), ctx.average_shown(r, "seen", section.spread),
               ctx.average_shown(r, "unseen", section.spread), ratio(seen, unseen)]
        if section.paper:
            row += _paper(section, r, 2)
        lines.append(_row(row))
    table = [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]
    return table + ctx.spread_note(replace(section, splits=section.splits or ("seen", "unseen")))


def _table(ctx: Context, number: int | None) -> Section:
    for s in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if s.table == number:
            return s
    raise ConfigError(f"{ctx.spec.path}: no report table {number}")


def _spread(ctx: Context, section: Section) -> list[str]:
    """One sentence once every run of a table has both averages: their range beside the paper's."""
    table = _table(ctx, section.of_table)
    seen = [ctx.average(r, "seen") for r in table.runs]
    unseen = [ctx.average(r, "unseen") for r in table.runs]
    if any(v is None for v in (*seen, *unseen)):
        return []
    ours = [f"{min(v):.1f}–{max(v):.1f}" for v in (seen, unseen)]  # type: ignore[type-var]
    paper = [f"{min(v)}–{max(v)}" for v in zip(*(table.paper[r] for r in table.runs), strict=True)]
    return [section.text.format(seen=ours[0], unseen=ours[1], paper_seen=paper[0], paper_unseen=paper[1])]


def _verdict(text: str, ok: bool | None, value: str) -> str:
    return f"{text}: not evaluated yet" if ok is None else f"{text}: {'met' if ok else 'not met'} ({value})"


def seed_spread(ctx: Context) -> dict[str, float]:
    """split -> the seed spread of every ``seeds`` section of the report (points): the largest difference between
    the averages of two seeds of one run; a split is left out until one seed pair has it evaluated."""
    spread: dict[str, float] = {}
    for section in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if section.kind == "seeds":
            for split, points in _section_spread(_seed_differences(ctx, section)).items():
                spread[split] = max(spread.get(split, 0.0), points)
    return spread


def _seed_splits(ctx: Context, section: Section) -> tuple[str, ...]:
    return section.splits or _table(ctx, section.of_table).splits or ("seen", "unseen")


def _seed_difference(ctx: Context, run: str, other: str, split: str) -> float | None:
    a, b = ctx.average(run, split), ctx.average(other, split)
    return None if a is None or b is None else abs(a - b)


def _seed_differences(ctx: Context, section: Section) -> dict[tuple[str, str], float | None]:
    """(run, split) -> the difference between the averages of a ``seeds`` section's pair (None: not evaluated)."""
    return {(run, split): _seed_difference(ctx, run, other, split)
            for run, other in section.seeds.items() for split in _seed_splits(ctx, section)}


def _section_spread(differences: Mapping[tuple[str, str], float | None]) -> dict[str, float]:
    """split -> the largest of a ``seeds`` section's evaluated differences (:func:`_seed_differences`)."""
    spread: dict[str, float] = {}
    for (_, split), difference in differences.items():
        if difference is not None:
            spread[split] = max(spread.get(split, 0.0), difference)
    return spread


def _shortfall(missed_by: float, split: str, spread: Mapping[str, float], digits: int) -> str:
    """``; N short, within the seed spread of S points`` when a point target is missed by no more than the
    measured seed spread of its split (the miss is then not a measured difference), else ""."""
    if split not in spread or missed_by > spread[split]:
        return ""
    return f"; {missed_by:.{digits}f} short, within the seed spread of {spread[split]:.{digits}f} points"


def _checked(ctx: Context, section: Section) -> tuple[list[str], dict[str, list[str]]]:
    """The verdicts of a ``targets`` section, one ``RUN: check: verdict; ...`` per row run, and the texts of the
    checks each run misses (measured, not asserted; with ``explain``, a target in points missed by no more than
    the report's seed spread, :func:`seed_spread`, says so)."""
    parts = []
    digits = section.digits
    missed: dict[str, list[str]] = {}
    spread = seed_spread(ctx) if section.explain else {}
    for run in section.runs:
        checks = []
        for check in section.checks:
            if check.run and check.run != run:
                continue
            value = ctx.average(run, check.split)
            ok: bool | None
            if check.kind == "at_least":
                ok = None if value is None else value >= check.value
                shown = pct(value, digits)
                if ok is False and value is not None:
                    shown += _shortfall(check.value - value, check.split, spread, digits)
            elif check.kind == "ratio":
                seen = ctx.average(run, "seen")
                ok = None if seen is None or value is None or not seen else value / seen >= check.value
                shown = ratio(seen, value)
            elif check.kind in ("keyframe_cm", "keyframe_deg", "loops"):
                ok, shown = _at_most(ctx, run, check)
            else:
                base = ctx.average(check.base, check.split)
                if check.kind == "beats":
                    ok = None if value is None or base is None else value >= base + check.value
                else:
                    ok = None if value is None or base is None else value < check.value * base
                shown = f"{pct(value, digits)} vs {pct(base, digits)}"
                if check.kind == "beats" and ok is False and value is not None and base is not None:
                    shown += _shortfall(base + check.value - value, check.split, spread, digits)
            checks.append(_verdict(check.text, ok, shown))
            if ok is False:
                missed.setdefault(run, []).append(check.text)
        if checks:
            parts.append(f"{run}: " + "; ".join(checks))
    return parts, missed


def _targets(ctx: Context, section: Section) -> list[str]:
    """Each target checked against the averages of each row run (:func:`_checked`), as one paragraph."""
    parts, _ = _checked(ctx, section)
    return [f"{section.text}: " + ". ".join(parts) + "."]


def _target_diagnosis(ctx: Context, section: Section) -> list[str]:
    """For every ``targets`` section of the report with ``explain``: a paragraph on what the diagnosis shows of
    each run that misses one of its targets (nothing when every target is met)."""
    out = []
    for targets in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if targets.kind != "targets" or not targets.explain:
            continue
        _, missed = _checked(ctx, targets)
        if missed:
            out.append("Where a target is missed, the diagnosis shows: " + " ".join(
                f"{run} (misses {', '.join(texts)}): {diagnosis_summary(ctx, run)}." for run, texts in missed.items()))
    return out


def _headline(ctx: Context, section: Section) -> list[str]:
    """The result in one paragraph and a small table: the section's text with ``{RUN_SPLIT}`` (the run's
    average, %) and ``{RUN_SPLIT_paper}`` (the paper's) filled in once every one is known, then one row per run
    and source (ours, the paper's) with a column per split."""
    digits = section.digits
    values: dict[str, str] = {}
    for run in section.runs:
        paper = section.paper.get(run, ())
        for i, split in enumerate(section.splits):
            values[f"{run}_{split}"] = pct(ctx.average(run, split), digits)
            values[f"{run}_{split}_paper"] = f"{paper[i]:.{digits}f}" if i < len(paper) else "–"
    lines = _head([section.column or "method", *section.splits])
    for run in section.runs:
        name = section.names.get(run, ctx.label(run))
        lines.append(_row([f"{name}, ours", *(values[f"{run}_{s}"] for s in section.splits)]))
        if run in section.paper:
            lines.append(_row([f"{name}, paper", *(values[f"{run}_{s}_paper"] for s in section.splits)]))
    known = "–" not in values.values()
    return ([section.text.format(**values)] if section.text and known else []) + ["\n".join(lines)]


def _at_most(ctx: Context, run: str, check: TargetCheck) -> tuple[bool | None, str]:
    """A ``keyframe_cm``, ``keyframe_deg`` or ``loops`` check of ``run`` (:class:`TargetCheck`): whether the
    measured value is at most the check's (``None``: not measured yet) and the value as shown."""
    if check.kind == "loops":
        share = loop_share(ctx.outcomes.loops, run, check.split)
        episodes = sum(n for (name, _, split), (_, n) in ctx.outcomes.loops.items()
                       if name == run and split == check.split)
        return (None, "–") if share is None else (share <= check.value, f"{share:.1f} % of {episodes} episodes")
    medians = kind_medians(ctx.outcomes.summaries.get(run, []), check.split).get(check.keyframe)
    if medians is None:
        return None, "–"
    value, unit = (medians[0], " cm") if check.kind == "keyframe_cm" else (medians[1], "°")
    return value <= check.value, f"{value:.1f}{unit}"


def _loops(ctx: Context, section: Section) -> list[str]:
    """Episodes with a grasp <-> lift loop (:func:`abm.experiments.arm_records.loops`) per row and split, summed
    over the tasks: ``loops / episodes (%)``."""
    runs = section.runs or tuple(dict.fromkeys(name for name, _, _ in ctx.outcomes.loops))
    splits = section.splits or tuple(s.split for s in ctx.spec.evaluation.splits)
    if not any(name in runs for name, _, _ in ctx.outcomes.loops):
        return []
    lines = _head([section.column or "arm", *splits])
    for run in runs:
        shown = []
        for split in splits:
            found = [v for (name, _, s), v in ctx.outcomes.loops.items() if name == run and s == split]
            looped, episodes = sum(k for k, _ in found), sum(n for _, n in found)
            shown.append(f"{looped} / {episodes} ({100 * looped / episodes:.0f} %)" if episodes else "–")
        lines.append(_row([ctx.label(run), *shown]))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]


def _caveats(ctx: Context, section: Section) -> list[str]:
    """The caveats of the runs that have cells, as one paragraph."""
    runs = {run for run, _, _ in ctx.cells}
    notes = [run.caveat for name, run in ctx.spec.runs.items() if run.caveat and name in runs]
    return [" ".join(notes)] if notes else []


def weakest_keyframes(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str = "seen") -> str:
    """One sentence per run: its keyframe kinds by median (over tasks) position error, worst first."""
    parts = []
    for run, rows in summaries.items():
        by_kind: dict[str, list[float]] = {}
        for row in rows:
            if row["split"] == split:
                by_kind.setdefault(row["kind"], []).append(row["position_cm_median"])
        if by_kind:
            ranked = sorted(((float(np.median(v)), k) for k, v in by_kind.items() if len(v) > 1), reverse=True)
            parts.append(f"{run}: " + ", ".join(f"{k} {cm:.1f} cm" for cm, k in ranked))
    if not parts:
        return ""
    return (f"Keyframe position error ({split} objects, teacher-forced on the expert's rollouts, median over the "
            "tasks that have the keyframe, worst first): " + "; ".join(parts) + ".")


def approach_yaw(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str = "seen",
                 task: str = "place_food") -> str:
    """One sentence: each run's rotation error where it chooses the yaw (the approach keyframe) against the
    grasp that follows it, median over the tasks, and on ``task``."""
    parts = []
    for run, rows in summaries.items():
        by_kind: dict[str, list[float]] = {}
        at_task: dict[str, float] = {}
        for row in rows:
            if row["split"] == split and row["kind"] in ("approach", "grasp"):
                by_kind.setdefault(row["kind"], []).append(row["rotation_deg_median"])
                if row["task"] == task:
                    at_task[row["kind"]] = row["rotation_deg_median"]
        if "approach" in by_kind and "grasp" in by_kind:
            parts.append(f"{run} {np.median(by_kind['approach']):.0f}° / {np.median(by_kind['grasp']):.0f}°"
                         + (f" ({task} {at_task['approach']:.0f}°)" if "approach" in at_task else ""))
    if not parts:
        return ""
    return (f"Rotation error ({split} objects, symmetry-aware, median over the tasks) at the approach keyframe, "
            "where the policy chooses the yaw from the scene, against the grasp keyframe that follows it from "
            "the approach pose: " + "; ".join(parts) + ".")


def keyframe_table(summaries: Mapping[str, Sequence[Mapping[str, Any]]], split: str,
                   order: Mapping[str, int]) -> str:
    """Median position error (cm) / rotation error (°, symmetry-aware) per task and keyframe kind, one column
    per diagnosis (tasks in ``order``)."""
    runs = list(summaries)
    rows: dict[tuple[str, str], dict[str, Mapping[str, Any]]] = {}
    for run in runs:
        for row in summaries[run]:
            if row["split"] == split:
                rows.setdefault((row["task"], row["kind"]), {})[run] = row
    lines = _head(["task", "keyframe", *runs])
    for (task, kind), by_run in sorted(rows.items(), key=lambda kv: (order.get(kv[0][0], 99), kv[0][0])):
        cells = [f"{r['position_cm_median']:.1f} / {r['rotation_deg_median']:.0f}" if (r := by_run.get(run))
                 else "–" for run in runs]
        lines.append(_row([task, kind, *cells]))
    return "\n".join(lines)


def _weakest(ctx: Context, section: Section) -> list[str]:
    return [t for s in section.splits or ("seen",) if (t := weakest_keyframes(ctx.outcomes.summaries, s))]


def _approach_yaw(ctx: Context, section: Section) -> list[str]:
    out = []
    for split in section.splits or ("seen",):
        text = approach_yaw(ctx.outcomes.summaries, split, section.task or "place_food")
        if text:
            out.append(text + (f" {section.note}" if section.note else ""))
    return out


def _zoo_eval(ctx: Context, section: Section) -> list[str]:
    """The timed ``abm zoo eval``, once it ran."""
    if ctx.outcomes.zoo_eval is None:
        return []
    table, seconds = ctx.outcomes.zoo_eval
    episodes = max((int(n) for n in re.findall(r"\(\d+/(\d+)\)", table)), default=0)
    head = next((line for line in table.splitlines() if line.startswith("| method |")), "")
    tasks = [c.strip() for c in head.strip("|").split("|")[1:] if c.strip() not in ("avg", "")]
    command = "abm zoo eval" + (f" --tasks {' '.join(tasks)}" if tasks else "") + (
        f" --episodes {episodes}" if episodes else "")
    each = f" ({', '.join(tasks)}; {episodes} episodes per task and split)" if tasks and episodes else ""
    return [f"Without training: `abm zoo eval` evaluates the zoo's abm and rvt models on seen and unseen objects "
            f"through the full pipeline. The table below{each} took {seconds / 60:.0f} min on this machine; "
            f"`{command}` reproduces it (the command's defaults are now the paper's 8 tasks at 5 episodes):"
            f"\n\n{table}"]


def _text(ctx: Context, section: Section) -> list[str]:
    return [section.text] if section.text else []


def _detail(ctx: Context, section: Section) -> list[str]:
    """Every run (or the section's) on every task of the splits."""
    runs = section.runs or tuple(ctx.spec.runs)
    splits = section.splits or ("seen", "unseen")
    lines = _head(["run"] + [f"{t} {s}" for s in splits for t in ctx.tasks(s)])
    for r in runs:
        lines.append(_row([r] + [cell(ctx.cells.get((r, t, s))) for s in splits for t in ctx.tasks(s)]))
    return ["\n".join(lines)]


def _keyframe_accuracy(ctx: Context, section: Section) -> list[str]:
    """Per split with diagnosis rows: a heading, the weakest keyframes, the section's text and the table."""
    summaries = ctx.outcomes.summaries
    out = []
    for split in section.splits or ("seen", "unseen"):
        if any(row["split"] == split for rows in summaries.values() for row in rows):
            out += [f"## Keyframe accuracy, {split} objects", weakest_keyframes(summaries, split), section.text,
                    keyframe_table(summaries, split, ctx.task_order())]
    return [b for b in out if b]


def _figures(ctx: Context, section: Section) -> list[str]:
    """The spec's figures as markdown images (drawn by :func:`draw_figures`)."""
    lines = [f"![{f.alt}]({f.file})" for f in ctx.spec.report.figures if (ctx.layout.root / f.file).is_file()]
    return ["\n".join(lines)] if lines else []


def _heading(ctx: Context, section: Section) -> list[str]:
    return [section.text]


def _evaluated(ctx: Context, name: str) -> bool:
    return any(run == name for run, _, _ in ctx.cells)


def _success_rows(ctx: Context, section: Section) -> list[str]:
    """Rows: the runs and variants evaluated; columns: (method and target,) every task × split, the split
    averages and unseen / seen."""
    splits = section.splits or ("seen", "unseen")
    head = [section.column or "run"] + (["method", "target from"] if section.describe else [])
    head += [f"{t} {s}" for s in splits for t in ctx.tasks(s)] + [f"{s} avg" for s in splits]
    both = "seen" in splits and "unseen" in splits
    lines = _head(head + (["unseen / seen"] if both else []))
    for name in section.runs:
        if not _evaluated(ctx, name):
            continue
        row = [ctx.label(name)]
        if section.describe:
            row += [ctx.method(name), ctx.describe(name)]
        row += [cell(ctx.cells.get((name, t, s))) for s in splits for t in ctx.tasks(s)]
        row += [pct(ctx.average(name, s), section.digits) for s in splits]
        if both:
            row.append(ratio(ctx.average(name, "seen"), ctx.average(name, "unseen")))
        lines.append(_row(row))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]


def _sentences(ctx: Context, section: Section) -> list[str]:
    """Each sentence whose two rows have both averages, one per line."""
    out = []
    for sentence in section.sentences:
        a, b = sentence.runs
        values = {f"{who}_{s}": ctx.average(run, s) for who, run in (("a", a), ("b", b)) for s in ("seen", "unseen")}
        if any(v is None for v in values.values()):
            continue
        shown = {k: f"{v:.0f}" for k, v in values.items()}
        out.append(sentence.text.format(a=a, b=b, **shown, ratio_seen=ratio(values["a_seen"], values["b_seen"]),
                                        ratio_unseen=ratio(values["a_unseen"], values["b_unseen"])))
    return ["\n".join(out)] if out else []


def _missing(ctx: Context, section: Section) -> list[str]:
    """The rows not evaluated (e.g. runs left out with --runs)."""
    missing = [ctx.label(n) for n in section.runs if not _evaluated(ctx, n)]
    return [f"{section.text or 'Not evaluated'}: {', '.join(missing)}."] if missing else []


KIND_ORDER = {"approach": 0, "grasp": 1, "lift": 2, "move": 3, "place": 4, "retreat": 5}


def _final_rows(ctx: Context) -> list[Mapping[str, Any]]:
    return [row for rows in ctx.outcomes.summaries.values() for row in rows if "@" not in str(row["method"])]


def _keyframe_rows(ctx: Context, section: Section) -> list[str]:
    """Final-checkpoint accuracy per method, task, split and keyframe kind."""
    rows = [r for r in _final_rows(ctx) if not section.kinds or r["kind"] in section.kinds]
    if not rows:
        return []
    lines = _head(["method", "task", "split", "keyframe", "position error cm (median)", "within 2 cm",
                   "rotation error ° (median)"])
    for r in sorted(rows, key=lambda r: (r["task"], KIND_ORDER.get(r["kind"], 9), r["kind"], r["split"],
                                         r["method"])):
        lines.append(f"| {r['method']} | {r['task']} | {r['split']} | {r['kind']} | {r['position_cm_median']:.1f} | "
                     f"{100 * r['within_grasp_tolerance']:.0f} % | {r['rotation_deg_median']:.0f} |")
    title = section.title.format(episodes=ctx.spec.diagnose.episodes if ctx.spec.diagnose else "?")
    return [title, "\n".join(lines)] if title else ["\n".join(lines)]


def _keyframe_curve(ctx: Context, section: Section) -> list[str]:
    """A keyframe kind's position error (seen objects; per task the median, then the mean over tasks) against
    training steps, with the training minutes at each step (``minutes_at_steps`` of the run summaries)."""
    kind = (section.kinds or ("grasp",))[0]
    curve: dict[str, dict[int, list[float]]] = {}
    for rows in ctx.outcomes.summaries.values():
        for r in rows:
            if r["kind"] != kind or r["split"] != "seen":
                continue
            method, _, step = str(r["method"]).partition("@")
            curve.setdefault(method, {}).setdefault(int(step) if step else -1, []).append(r["position_cm_median"])
    if not any(len(v) > 1 for v in curve.values()):
        return []
    minutes = {e["name"]: {int(k): v for k, v in (e.get("minutes_at_steps") or {}).items()}
               for e in ctx.outcomes.entries}
    steps = sorted({s for v in curve.values() for s in v if s >= 0})
    lines = ["| method | " + " | ".join(f"step {s}" for s in steps) + " | final |", "|---" * (len(steps) + 2) + "|"]
    for method, by_step in sorted(curve.items()):
        at = minutes.get(method, {})
        cells = [(f"{sum(by_step[s]) / len(by_step[s]):.1f}" + (f" ({at[s]:.0f} min)" if s in at else ""))
                 if s in by_step else "–" for s in steps]
        final = by_step.get(-1)
        cells.append(f"{sum(final) / len(final):.1f}" if final else "–")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]


def _keyframe_compare(ctx: Context, section: Section) -> list[str]:
    """Median rotation error (°) / position error (cm) per task, split and keyframe kind, one column per run."""
    runs = section.runs or tuple(ctx.outcomes.summaries)
    found: dict[tuple[str, str, str], dict[str, Mapping[str, Any]]] = {}
    for run in runs:
        for r in ctx.outcomes.summaries.get(run, []):
            if not section.kinds or r["kind"] in section.kinds:
                found.setdefault((r["task"], r["split"], r["kind"]), {})[run] = r
    if not found:
        return []
    order = ctx.task_order()
    lines = _head(["task", "split", "keyframe", *(section.names.get(r, r) for r in runs)])
    for (task, split, kind), by_run in sorted(found.items(), key=lambda kv: (
            order.get(kv[0][0], 99), kv[0][0], kv[0][1], KIND_ORDER.get(kv[0][2], 9))):
        lines.append(_row([task, split, kind] + [
            f"{hit['rotation_deg_median']:.0f} / {hit['position_cm_median']:.1f}" if (hit := by_run.get(run))
            else "–" for run in runs]))
    return [section.title, "\n".join(lines)] if section.title else ["\n".join(lines)]


def _grounding_quality(ctx: Context, section: Section) -> list[str]:
    """Mask quality of one grounding configuration on the evaluated tasks' scenes (the records of
    ``benchmarks/grounding_quality.py``)."""
    path = ctx.layout.root / section.source
    if not path.is_file():
        return []
    tasks = sorted({t for s in ctx.spec.evaluation.splits for t in s.tasks})
    rows = [r for r in json.loads(path.read_text()).get("records", []) if r["config"] == section.config
            and r["task"] in tasks]
    if not rows:
        return []
    lines = _head(["task", "split", "scenes", "mask IoU", "hit rate", "top-1 point on the target"])
    for t in tasks:
        for s in ("seen", "unseen"):
            for r in (r for r in rows if r["task"] == t and r["split"] == s):
                lines.append(f"| {t} | {s} | {r['n']} | {r['iou']:.2f} | {100 * r['hit_rate']:.0f} % | "
                             f"{100 * r['top1']:.0f} % |")
    return [section.title.format(config=section.config), "\n".join(lines)]


def _outcome_tables(ctx: Context, section: Section) -> list[str]:
    """Per split, the tables ``abm eval`` wrote (``results.md``, kept as ``RUN_SPLIT.md``) of every run."""
    out = []
    for split in section.splits or tuple(s.split for s in ctx.spec.evaluation.splits):
        tables = []
        for name in ctx.spec.runs:
            path = ctx.layout.eval_dir(name, split) / "results.md"
            if path.is_file():
                tables.append("\n".join(line for line in path.read_text().strip().splitlines()
                                        if "report.html" not in line).strip())
        if tables:
            out += [f"## {split}", *tables]
    return out


# ------------------------------------------------------------------------------------ seeds and diagnosis
def _seeds(ctx: Context, section: Section) -> list[str]:
    """The seed spread of a table: each run beside the same run with another seed (``seeds``), the largest such
    difference per split as the spread, and the differences between the table's rows that exceed it."""
    table = _table(ctx, section.of_table)
    splits = _seed_splits(ctx, section)
    digits = section.digits
    names = {**table.names, **section.names}
    lines = _head(["run", "other seed", *(f"{s} {x}" for s in splits for x in ("avg", "other seed", "difference"))])
    differences = _seed_differences(ctx, section)
    for run, other in section.seeds.items():
        row = [names.get(run, run), other]
        for split in splits:
            row += [ctx.average_shown(run, split, True, digits), ctx.average_shown(other, split, True, digits),
                    pct(differences[run, split], digits)]
        lines.append(_row(row))
    spread = _section_spread(differences)
    sentences = []
    for split in splits:
        if split not in spread:
            sentences.append(f"{split}: the seed spread is not measured yet (each seed pair needs every task "
                             "evaluated)")
            continue
        averages = {r: v for r in table.runs if (v := ctx.average(r, split)) is not None}
        exceeding = [f"{names.get(a, a)} vs {names.get(b, b)} {abs(averages[a] - averages[b]):.{digits}f}"
                     for i, a in enumerate(averages) for b in list(averages)[i + 1:]
                     if abs(averages[a] - averages[b]) > spread[split]]
        sentences.append(f"{split}: seed spread {spread[split]:.{digits}f} points; differences between the table's "
                         f"rows larger than it: {', '.join(exceeding) if exceeding else 'none'}")
    text = (f"Seed spread of Table {table.table}: the largest difference between the averages of two seeds of one "
            "run (same data, recipe and evaluation scenes; ± the standard error over the repeats). " +
            "; ".join(sentences) + ".")
    return [section.title, "\n".join(lines), text] if section.title else ["\n".join(lines), text]


def kind_medians(rows: Sequence[Mapping[str, Any]], split: str) -> dict[str, tuple[float, float, float | None]]:
    """Keyframe kind -> (position error cm, rotation error °, a random yaw's error ° or ``None`` when the
    diagnosis predates it), each the median over the tasks of the per-task medians of ``split``."""
    by_kind: dict[str, list[Mapping[str, Any]]] = {}
    for row in rows:
        if row["split"] == split:
            by_kind.setdefault(row["kind"], []).append(row)
    out = {}
    for kind in sorted(by_kind, key=lambda k: (KIND_ORDER.get(k, 9), k)):
        found = by_kind[kind]
        chance = [float(r["yaw_chance_deg"]) for r in found if "yaw_chance_deg" in r]
        out[kind] = (float(np.median([r["position_cm_median"] for r in found])),
                     float(np.median([r["rotation_deg_median"] for r in found])),
                     float(np.median(chance)) if chance else None)
    return out


def probe_result(ctx: Context, run: str, task: str) -> tuple[float, bool, list[str]] | None:
    """A skill-text probe of ``run`` on ``task``: (the own skill text's distance cm from the expert's keyframe,
    whether it is within the target, the other skill texts whose prediction stays within the target of the
    own text's: the ones the policy does not tell apart), or ``None`` before it ran."""
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    found = ctx.outcomes.probes.get((run, task))
    if probe is None or found is None:
        return None
    own = next(r for r in found["rows"] if r["own"])
    same = [str(r["skill"]) for r in found["rows"] if not r["own"] and r["moved_cm_median"] < probe.within_cm]
    return float(own["position_cm_median"]), own["position_cm_median"] <= probe.within_cm, same


def failure_counts(ctx: Context, run: str, splits: Sequence[str] | None = None) -> dict[str, int]:
    """Failed rollouts of ``run`` by reason, summed over the tasks (and ``splits``; default all), most first."""
    total: dict[str, int] = {}
    for (name, _, split), rate in ctx.cells.items():
        if name == run and (splits is None or split in splits):
            for reason, n in (rate.get("failures") or {}).items():
                total[reason] = total.get(reason, 0) + int(n)
    return dict(sorted(total.items(), key=lambda kv: -kv[1]))


def diagnosis_summary(ctx: Context, run: str) -> str:
    """What the diagnosis shows of ``run``, in a sentence: the keyframe kinds with the largest position errors and
    those whose rotation is no better than a random yaw (seen objects), the skill-text probe, and why its
    rollouts failed."""
    parts = []
    kinds = kind_medians(ctx.outcomes.summaries.get(run, []), "seen")
    if kinds:
        worst = sorted(kinds.items(), key=lambda kv: -kv[1][0])[:2]
        parts.append("the largest keyframe errors (seen objects) at " + " and ".join(
            f"{kind} ({cm:.1f} cm, {deg:.0f}°)" for kind, (cm, deg, _) in worst))
        at_chance = [f"{kind} ({deg:.0f}° against {chance:g}°)" for kind, (_, deg, chance) in kinds.items()
                     if chance and deg >= 0.8 * chance]
        if at_chance:
            parts.append("a rotation no better than a random yaw's at " + ", ".join(at_chance))
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    if probe is not None:
        results = [(task, r) for task in probe.tasks if (r := probe_result(ctx, run, task)) is not None]
        if results:
            parts.append(f"the skill-text probe at the {probe.kind} keyframe: " + ", ".join(
                f"{task}'s own text {cm:.1f} cm from the expert's ({'within' if ok else 'not within'} "
                f"{probe.within_cm:g} cm)" for task, (cm, ok, _) in results))
    failures = failure_counts(ctx, run)
    if failures:
        parts.append("its failed rollouts: " + ", ".join(f"{reason} {n}" for reason, n in failures.items()))
    return "; ".join(parts) if parts else "no diagnosis of it yet"


def _diagnosis(ctx: Context, section: Section) -> list[str]:
    """Per model: keyframe accuracy per kind beside a random yaw's error, the skill-text probe, and the failure
    reasons of its rollouts."""
    runs = section.runs or tuple(ctx.spec.runs)
    out = [section.title] if section.title else []
    for split in section.splits or ("seen",):
        rows = {name: kind_medians(found, split) for name, found in ctx.outcomes.summaries.items()
                if name.split("@")[0] in runs}
        rows = {name: kinds for name, kinds in rows.items() if kinds}
        kinds = [k for k in dict.fromkeys(k for found in rows.values() for k in found)
                 if not section.kinds or k in section.kinds]
        if not rows or not kinds:
            continue
        lines = _head(["model", *kinds])
        for name, found in rows.items():
            lines.append(_row([name, *(f"{found[k][0]:.1f} / {found[k][1]:.0f}"
                                       + (f" ({found[k][2]:g})" if found[k][2] is not None else "")
                                       if k in found else "–" for k in kinds)]))
        out += [f"Keyframe accuracy per kind, {split} objects (the expert's rollouts, teacher-forced): the median "
                "over the tasks of the median position error (cm) / rotation error (°, symmetry-aware), in brackets "
                "a random yaw's error for the keyframe's symmetry (45° two-fold, 22.5° four-fold, 0 round): a "
                "rotation error near it is chance. RUN@oracle: fed the simulator's mask.", "\n".join(lines)]
    probe = ctx.spec.diagnose.skill_text if ctx.spec.diagnose is not None else None
    probed = [r for r in runs if probe is not None and r in probe.runs
              and any(probe_result(ctx, r, t) for t in probe.tasks)]
    if probe is not None and probed:
        lines = _head(["model", *probe.tasks])
        for run in probed:
            cells = []
            for task in probe.tasks:
                result = probe_result(ctx, run, task)
                cells.append("–" if result is None else f"{result[0]:.1f} cm, {'met' if result[1] else 'not met'}"
                             f" ({len(result[2])} other text{'' if len(result[2]) == 1 else 's'} within "
                             f"{probe.within_cm:g} cm of it)")
            lines.append(_row([run, *cells]))
        out += [f"Skill-text probe at the {probe.kind} keyframe ({probe.episodes} {probe.split} scenes per task, "
                "teacher-forced; `benchmarks/skill_text_probe.py`): how far (median, cm) the prediction with the "
                "scene's own skill text lands from the expert's destination, against the target of "
                f"{probe.within_cm:g} cm, and how many of the other tasks' skill texts, worded about the same "
                f"object, move it less than {probe.within_cm:g} cm (texts the policy does not tell apart):",
                "\n".join(lines)]
    splits = [s.split for s in ctx.spec.evaluation.splits]
    failed = [(run, split, counts) for run in runs for split in splits
              if (counts := failure_counts(ctx, run, [split]))]
    if failed:
        reasons = list(dict.fromkeys(reason for _, _, counts in failed for reason in counts))
        lines = _head(["model", "split", "failed / episodes", *reasons])
        for run, split, counts in failed:
            episodes = sum(int(r["episodes"]) for (n, _, s), r in ctx.cells.items() if n == run and s == split)
            lines.append(_row([run, split, f"{sum(counts.values())} / {episodes}",
                               *(str(counts.get(reason, 0)) for reason in reasons)]))
        out += ["Why the rollouts failed (episodes per reason, summed over the tasks; per task in the records JSON): "
                "grasp missed: the gripper never held the target; timeout: it held it but the task was not done "
                "within the step limit; IK unreachable, motion blocked, collision: the arm could not follow a "
                "keyframe; crashed: the rollout raised.", "\n".join(lines)]
    return out


WRITERS: dict[str, Callable[[Context, Section], list[str]]] = {
    "setup": _setup, "per_task": _per_task, "per_run": _per_run, "averages": _averages, "spread": _spread,
    "targets": _targets, "caveats": _caveats, "weakest_keyframes": _weakest, "approach_yaw": _approach_yaw,
    "zoo_eval": _zoo_eval, "text": _text, "detail": _detail, "keyframe_accuracy": _keyframe_accuracy,
    "figures": _figures, "heading": _heading, "success_rows": _success_rows, "sentences": _sentences,
    "missing": _missing, "keyframe_rows": _keyframe_rows, "keyframe_curve": _keyframe_curve,
    "keyframe_compare": _keyframe_compare, "grounding_quality": _grounding_quality, "outcome_tables": _outcome_tables,
    "seeds": _seeds, "diagnosis": _diagnosis, "loops": _loops, "target_diagnosis": _target_diagnosis,
    "headline": _headline,
}
#: section kinds whose tables do not call for :func:`reproduce`'s line (zoo_eval names its own command, a
#: headline stands at the top of a README, where the tables it summarises are linked)
NO_REPRODUCE = ("zoo_eval", "headline")


def reproduce(ctx: Context) -> str:
    """The line under a block's tables: the command that reproduces them."""
    name = ctx.spec.name if ctx.spec.path.resolve().parent == SPECS else spec_name(ctx.spec, ctx.layout)
    return (f"Reproduce: `abm experiment run {name}` (every stage, resuming from the kept outcomes; "
            f"`abm experiment run {name} --stages report` rewrites the tables above from them alone).")


def blocks(ctx: Context, sections: Sequence[Section], into: str = "") -> list[str]:
    """The paragraphs of ``sections``, in order (empty ones and repeats of an earlier one left out), then, when
    one of them wrote a table, :func:`reproduce`'s line. ``into`` (``readme`` or ``document``) leaves out the
    sections meant only for the other (``Section.only``)."""
    out: list[str] = []
    tables = False
    for section in sections:
        if into and section.only and section.only != into:
            continue
        writer = WRITERS.get(section.kind)
        if writer is None:
            raise ConfigError(f"{ctx.spec.path}: the report cannot write {section.kind!r} sections yet")
        written = [b for b in writer(ctx, section) if b and b not in out]
        out += written
        if section.kind not in NO_REPRODUCE:
            tables = tables or any("\n|---" in b or b.startswith("|---") for b in written)
    return out + [reproduce(ctx)] if tables else out


def shows_dash(paragraphs: Sequence[str]) -> bool:
    """Whether a table among ``paragraphs`` has a cell that shows "–" (not evaluated yet)."""
    return any(c.strip().strip("*") == "–" for p in paragraphs for line in p.splitlines() if line.startswith("|")
               for c in line.strip().strip("|").split("|"))


def provenance(spec: ExperimentSpec, layout: Layout, dashes: bool = True) -> str:
    """The report's first line: what wrote it, from which spec, from which kept outcomes (and, when a table of
    the report has a "–" cell, what "–" means)."""
    kept, source = layout.show(layout.kept), spec_name(spec, layout)
    what, tail = ("evaluation JSON", "; cells not evaluated yet show –" if dashes else "") if (
        spec.evaluation.splits) else ("diagnosis JSON", "")
    return (f"Written by `abm experiment run {spec.name}` ([{source}]({source})) from the {what} kept in "
            f"[{kept}/]({kept}/){tail}.")


def relink(text: str, folder: str) -> str:
    """``text`` with its root-relative markdown links rewritten relative to ``folder`` (both root-relative)."""
    def fix(match: re.Match[str]) -> str:
        target = match.group(1)
        if "://" in target or target.startswith(("#", "/", "mailto:")) or folder in ("", "."):
            return match.group(0)
        path, hash_, anchor = target.partition("#")
        new = Path(os.path.relpath(path, folder)).as_posix() + ("/" if path.endswith("/") else "")
        return f"]({new}{hash_}{anchor})"

    return _LINK.sub(fix, text)


@dataclass
class Written:
    """The texts of one report (what :func:`write_report` writes)."""

    summary: str
    document: str
    block: str
    blocks: dict[str, str]
    records: list[dict[str, Any]]
    zoo: list[dict[str, Any]] | None
    zoo_readme: str


def records(spec: ExperimentSpec, cells: Cells) -> list[dict[str, Any]]:
    """The machine-readable cells: one record per table a cell belongs to (its run and split)."""
    tables = [s for s in (*spec.report.summary, *spec.report.details) if s.table is not None]
    out = []
    for (run, task, split), rate in sorted(cells.items()):
        spec_run = spec.runs.get(run)
        for table in sorted(tables, key=lambda s: s.table or 0):
            if run not in table.runs or split not in table.splits or spec_run is None:
                continue
            record = {"table": table.table, "run": run, "label": spec_run.label, "method": spec_run.method,
                      "grounder": spec_run.grounding, "task": task, "split": split, "successes": successes(rate),
                      "episodes": rate["episodes"], "mean": rate["mean"], "std": rate["std"],
                      "per_repeat": rate["per_repeat"]}
            if "failures" in rate:  # evaluations since failure reasons are counted (abm.evaluation.results)
                record["failures"] = rate["failures"]
            out.append(record)
    return out


def spec_name(spec: ExperimentSpec, layout: Layout) -> str:
    """The spec's file as a reader finds it: ``src/abm/configs/experiments/NAME.yaml`` for a built-in one (the
    checkout's ``configs/`` is a symlink to ``src/abm/configs``, which GitHub does not follow in links)."""
    if spec.path.resolve().parent == SPECS:
        return f"src/abm/configs/experiments/{spec.path.name}"
    shown = layout.show(spec.path.resolve())  # relative to the root, also when the root is given relative
    return spec.path.name if Path(shown).is_absolute() else shown  # outside the root: no machine's folder


def zoo_readme(spec: ExperimentSpec, layout: Layout, entries: Sequence[Mapping[str, Any]]) -> str:
    """The zoo's README: what wrote it, then one row per model (with its edition when the zoo holds a later
    edition's models)."""
    source = spec_name(spec, layout)
    link = relink(f"]({source})", layout.show(layout.zoo or layout.root))[2:-1]
    editions = any("edition" in e for e in entries)
    lines = ["# Model zoo", "", f"Written by `abm experiment run {spec.name}` ([{source}]({link}))."
             + (f" {spec.report.zoo_note}" if spec.report.zoo_note else ""), "",
             *_head(["name", *(["edition"] if editions else []), "what", "method", "grounder", "steps", "train min",
                     "MB", "sha256"])]
    for e in entries:
        shown = [str(edition(dict(e)))] if editions and e.get("method") != "clip" else ["–"] if editions else []
        lines.append(_row([e["name"], *shown, e.get("label") or "–", e["method"], str(e.get("grounder", "–")),
                           str(e.get("steps", "–")), str(e.get("train_minutes", "–")), f"{e['size_bytes'] / 1e6:.1f}",
                           f"`{e['sha256'][:16]}…`"]))
    return "\n".join(lines) + "\n"


def newest_edition(spec: ExperimentSpec, entries: Sequence[Mapping[str, Any]]) -> bool:
    """Whether no model in the zoo comes from a later edition than the spec's (then the spec writes the zoo's
    README; an earlier edition's report leaves it to the newest one)."""
    return all(edition(dict(e)) <= spec.edition for e in entries)


def compose(spec: ExperimentSpec, layout: Layout, outcomes: Outcomes) -> Written:
    """Every text of the report (nothing written yet)."""
    ctx = Context(spec, outcomes, layout)
    in_document = blocks(ctx, spec.report.summary, "document")
    in_readme = blocks(ctx, spec.report.summary, "readme")
    details = blocks(ctx, spec.report.details, "document")
    head = provenance(spec, layout, shows_dash([*in_document, *in_readme, *details]))
    summary = "\n\n".join([head, *in_document]) + "\n"
    document = relink(f"# {spec.report.title}\n\n" + "\n\n".join([summary.rstrip("\n"), *details]) + "\n",
                      Path(spec.report.document).parent.as_posix()) if spec.report.document else ""
    block = "\n\n".join([head, *in_readme]) + "\n" + (
        f"Full report: [{spec.report.document}]({spec.report.document}).\n" if spec.report.document else "")
    folder = Path(spec.report.readme).parent.as_posix()
    if spec.report.readme:
        block = relink(block, folder)
    extra = {name: relink("\n\n".join(blocks(ctx, sections, "readme")) + "\n", folder)
             for name, sections in spec.report.blocks.items()}
    zoo = (outcomes.index if outcomes.index is not None else outcomes.entries) if layout.zoo is not None else None
    return Written(summary=summary, document=document, block=block, blocks=extra,
                   records=records(spec, outcomes.cells),
                   zoo=zoo, zoo_readme=zoo_readme(spec, layout, zoo) if zoo is not None else "")


# -------------------------------------------------------------------------------------------------- writing
def replace_block(text: str, name: str, body: str, source: str = "README") -> str:
    """``text`` with what stands between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` replaced by ``body``."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    if start not in text or end not in text:
        raise DataError(f"{source} has no {start} ... {end} block to replace")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{body}{end}{tail}"


def block_of(text: str, name: str) -> str:
    """What stands between the markers of block ``name`` (without the newline after the start marker)."""
    start, end = f"<!-- {name}:start -->\n", f"<!-- {name}:end -->"
    return text.split(start, 1)[1].split(end, 1)[0]


class NotOwnedError(OutputError):
    """The report would write a file it does not own (outside the root, the spec itself, a file it did not
    write): it writes nothing there."""


def _records_file(text: str) -> bool:
    """Whether ``text`` is a report's records (a JSON list of cells, each naming its table and run)."""
    try:
        data = json.loads(text)
    except ValueError:
        return False
    return isinstance(data, list) and all(isinstance(r, dict) and {"table", "run"} <= set(r) for r in data)


def _zoo_index_file(text: str) -> bool:
    """Whether ``text`` is a zoo index (a JSON list of entries, each with a name)."""
    try:
        data = json.loads(text)
    except ValueError:
        return False
    return isinstance(data, list) and all(isinstance(e, dict) and "name" in e for e in data)


#: what marks a file as the report's own, per kind of file it writes (``spec.name`` filled in): the provenance
#: line of a document (:func:`provenance`), the shape of the records and of the zoo index, the zoo README's head
OWNED: dict[str, Callable[[str, str], bool]] = {
    "document": lambda text, name: text.startswith("# ") and text.split("\n", 3)[2:3] != [] and text.split(
        "\n", 3)[2].startswith(f"Written by `abm experiment run {name}` ("),
    "records": lambda text, name: _records_file(text),
    "arm records": lambda text, name: is_arm_records(text),
    "zoo index": lambda text, name: _zoo_index_file(text),
    "zoo README": lambda text, name: text.startswith("# Model zoo\n\nWritten by `abm experiment run "),
}


def report_files(spec: ExperimentSpec, layout: Layout) -> list[tuple[Path, str]]:
    """``(file, what it is)`` of every file the report writes outside KEPT (:data:`OWNED` names the kinds)."""
    report, root = spec.report, layout.root
    files = [(root / name, what) for name, what in ((report.records, "records"), (report.document, "document"),
                                                     (report.readme, "README block"),
                                                     (report.arm_records, "arm records")) if name]
    if layout.zoo is not None:
        files.append((layout.zoo / "index.json", "zoo index"))
        if report.zoo_readme:
            files.append((layout.zoo / "README.md", "zoo README"))
    return files + [(root / figure.file, "figure") for figure in report.figures]


def check_owned(path: Path, spec: ExperimentSpec, layout: Layout, what: str) -> None:
    """Refuse (:class:`NotOwnedError`) to write ``path`` unless the report owns it: inside the root once links
    are followed, not the spec, and either new or holding the mark of what it writes (:data:`OWNED`; a README
    block is replaced between its markers only, :func:`replace_block`)."""
    fix = "name another file in the spec's report section, or remove that file if it may be replaced"
    if not is_inside(path, layout.root):
        raise NotOwnedError(f"the report's {what} {layout.show(path)} is outside the root {layout.root}: {fix}")
    if path.resolve() == spec.path.resolve():
        raise NotOwnedError(f"the report's {what} {layout.show(path)} is the spec itself: {fix}")
    if not (path.exists() or path.is_symlink()) or what == "README block":
        return
    if path.is_symlink() or not path.is_file():
        owned = False
    elif what == "figure":  # a PNG replaced by a PNG
        with path.open("rb") as f:
            owned = f.read(8) == b"\x89PNG\r\n\x1a\n"
    else:
        try:
            owned = OWNED[what](path.read_text(encoding="utf-8"), spec.name)
        except (OSError, UnicodeDecodeError):
            owned = False
    if not owned:
        raise NotOwnedError(f"the report's {what} {layout.show(path)} exists and was not written by abm experiment "
                            f"run {spec.name} (the report replaces only files it wrote): {fix}")


def _write(path: Path, text: str) -> bool:
    """Write ``text`` when it differs from the file's; returns whether it did."""
    if path.is_file() and path.read_text() == text:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return True


def keep_training_log(run_dir: Path, path: Path, max_rows: int = 200) -> None:
    """A compact copy of a run's loss curve (the loss columns its log has): at most ``max_rows`` rows, each the
    mean of a window of consecutive logged steps (a logged loss is one batch's, too noisy to read alone) at the
    window's last step, which for the last window is the run's last logged step."""
    with (run_dir / "log.csv").open() as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        columns = [c for c in LOSS_COLUMNS if c in (reader.fieldnames or ())]  # the zoom's only in two-stage runs
    width = -(-len(rows) // max_rows) if rows else 1
    kept = []
    for start in range(0, len(rows), width):
        window = rows[start:start + width]
        row = {"step": window[-1]["step"]}
        for column in columns[1:]:
            values = [float(r[column]) for r in window if r.get(column) not in (None, "")]
            row[column] = f"{sum(values) / len(values):.6g}" if values else ""
        kept.append(row)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(kept)


def draw_figures(spec: ExperimentSpec, layout: Layout, cells: Cells) -> list[Path]:
    """Draw the spec's figures from the kept outcomes; returns the PNGs drawn."""
    if not spec.report.figures:
        return []
    from abm.evaluation.plots import keyframe_error_curve, loss_curves, success_chart  # matplotlib: only here

    drawn = []
    for figure in spec.report.figures:
        path = layout.root / figure.file
        names = list(figure.runs) or [*spec.runs, *(v.name for v in spec.evaluation.variants)]
        if figure.kind == "success":
            labels = {v.name: v.label for v in spec.evaluation.variants}  # runs by name, variants by label
            rates = [{**rate, "method": labels.get(run, run)} for (run, _, _), rate in sorted(cells.items())
                     if run in names]
            if rates:
                shown = [labels.get(n, n) for n in names]
                drawn.append(success_chart(rates, path, methods=[n for n in shown if any(
                    r["method"] == n for r in rates)]))
        elif figure.kind == "losses":
            logs = {n: list(csv.DictReader((layout.kept / f"training_{n}.csv").open())) for n in names
                    if (layout.kept / f"training_{n}.csv").is_file()}
            if logs:
                drawn.append(loss_curves(logs, path))
        else:
            files = [layout.kept / f"keyframe_accuracy_{n}.json" for n in names]
            rows = [row for p in files if p.is_file() for row in json.loads(p.read_text())["summary"]]
            if rows:
                drawn.append(keyframe_error_curve(rows, path))
    return drawn


def write_report(spec: ExperimentSpec, layout: Layout, figures: bool = True) -> Written:
    """Write every generated file of the report (see the module docstring); returns their texts."""
    for path, what in report_files(spec, layout):  # before anything is written: a refusal leaves every file as is
        check_owned(path, spec, layout, what)
    if layout.zoo is None:  # an experiment without a zoo keeps its runs' summaries itself
        entries = kept_run_summaries(spec, layout)
        if entries:
            _write(layout.kept / "runs.json", json.dumps(entries, indent=1) + "\n")
    for name in spec.runs:  # every run's loss curve, while its folder is here (the export also keeps it)
        if (layout.run_dir(name) / "log.csv").is_file():
            keep_training_log(layout.run_dir(name), layout.kept / f"training_{name}.csv")
    outcomes = collect(spec, layout)
    if figures:
        draw_figures(spec, layout, outcomes.cells)
    written = compose(spec, layout, outcomes)
    if written.zoo is not None and layout.zoo is not None:
        _write(layout.zoo / "index.json", json.dumps(written.zoo, indent=2) + "\n")
        if spec.report.zoo_readme and newest_edition(spec, written.zoo):
            _write(layout.zoo / "README.md", written.zoo_readme)
    if spec.report.records:
        _write(layout.root / spec.report.records, json.dumps(written.records, indent=1) + "\n")
    if spec.report.arm_records:
        records_of_arms = arm_records(spec, outcomes.cells, outcomes.summaries, outcomes.loops)
        _write(layout.root / spec.report.arm_records, json.dumps(records_of_arms, indent=1) + "\n")
    if spec.report.document:
        _write(layout.root / spec.report.document, written.document)
    if spec.report.readme:
        readme = layout.root / spec.report.readme
        text = replace_block(readme.read_text(), spec.report.block, written.block, spec.report.readme)
        for name, body in written.blocks.items():
            text = replace_block(text, name, body, spec.report.readme)
        _write(readme, text)
    return written
