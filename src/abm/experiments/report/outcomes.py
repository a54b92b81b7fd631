"""What a report is written from (:class:`Outcomes`): the kept evaluation cells, diagnoses, run summaries, zoo
index, stage times and machines of an experiment, read by :func:`collect`."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from abm.experiments.arm_records import Loops, loop_counts
from abm.experiments.report.numbers import Cells
from abm.experiments.report.runs import describe_run, minutes_at_steps, training_summary
from abm.experiments.spec import ExperimentSpec
from abm.experiments.state import Layout, kept_pairs, machines, stage_minutes
from abm.files import sha256_file


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
        probes: the skill-text probes (the ``skill_text`` diagnosis' JSON) by (run, task).
        index: the whole zoo index the report writes (with other specs' entries), or ``None`` without a zoo.
        loops: grasp <-> lift loops per (run or variant, task, split): (episodes that loop, episodes)
            (:func:`abm.experiments.arm_records.loop_counts`).
        destination_grounding: the rows of the ``destination_grounding`` diagnosis (the spec's CLIP grounder on
            each task's target and destination), ``[]`` before it ran.
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
    destination_grounding: list[dict[str, Any]] = field(default_factory=list)


def collect_cells(spec: ExperimentSpec, layout: Layout, kept: bool = False) -> Cells:
    """``(run, task, split) -> rate`` from every evaluation JSON of the spec's runs and variants under OUT (with
    ``kept``, one OUT lacks from its committed copy in KEPT: what a fresh clone has before a run restores it)."""
    copies = dict(kept_pairs(spec, layout)) if kept else {}
    cells: Cells = {}
    for name in [*spec.runs, *(v.name for v in spec.evaluation.variants)]:
        for split in spec.evaluation.splits:
            path = layout.eval_dir(name, split.split) / "results.json"
            path = path if path.is_file() else copies.get(path, path)
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


def zoo_index(spec: ExperimentSpec, layout: Layout, gate_open: bool | None = None) -> list[dict[str, Any]]:
    """Every exported model of the spec (and the benchmark CLIP) as the zoo index describes it, with the
    entries other specs exported into the same zoo (another edition's: other names) kept as they are.

    A model's entry keeps what the index knew (on a fresh clone the run folder is gone) and is refreshed from
    its run folder when that is here; the file's size and sha256 are read anew. A later edition's entries
    also record their ``edition``, ``experiment``, ``run`` and whether ``abm zoo eval`` compares them
    (``compared``: the spec's ``evaluation.zoo_eval``; :func:`abm.zoo.pick`; for a spec with a README gate only
    once ``gate_open``, see :func:`compared_now`). Order: the index's, with the
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
                          "compared": compared_now(spec, name, gate_open, entry.get("compared") is True)})
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


def compared_now(spec: ExperimentSpec, run: str, gate_open: bool | None, was: bool = False) -> bool:
    """Whether ``abm zoo eval`` runs the spec's model of ``run`` (its index entry's ``compared``): a model of the
    spec's ``evaluation.zoo_eval``, and for a spec with a README gate (``report.readme_when``) only once the gate
    is open, so the zoo's evaluation switches to an edition together with the README's tables. ``gate_open``
    ``None`` (an export, which does not know the gate) keeps what the index said (``was``)."""
    if run not in spec.evaluation.zoo_eval:
        return False
    if spec.report.readme_when is None:
        return True
    return was if gate_open is None else gate_open


def mark_compared(spec: ExperimentSpec, entries: list[dict[str, Any]], gate_open: bool) -> list[dict[str, Any]]:
    """``entries`` (a zoo index) with the spec's own models marked ``compared`` as :func:`compared_now` says for
    ``gate_open``; other specs' entries unchanged."""
    return [{**e, "compared": compared_now(spec, e["run"], gate_open)}
            if e.get("experiment") == spec.name and "run" in e else e for e in entries]


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
                    loops=loop_counts(spec, layout) if _reads_loops(spec) else {},
                    destination_grounding=destination_grounding(spec, layout))


def destination_grounding(spec: ExperimentSpec, layout: Layout) -> list[dict[str, Any]]:
    """The rows of the spec's ``destination_grounding`` diagnosis (``[]``: not part of it, or not run yet)."""
    path = layout.destination_grounding
    measured = spec.diagnose is not None and spec.diagnose.destination_grounding is not None and path.is_file()
    return list(json.loads(path.read_text())) if measured else []


def _reads_loops(spec: ExperimentSpec) -> bool:
    """Whether the report shows grasp <-> lift loops (its arm records, a ``loops`` section or check), which are
    read from every evaluation's outcome archive."""
    sections = (*spec.report.summary, *spec.report.details)
    return bool(spec.report.arm_records) or any(
        s.kind == "loops" or any(c.kind == "loops" for c in s.checks) for s in sections)
