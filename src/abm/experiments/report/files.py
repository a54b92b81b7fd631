"""Writing a report (:func:`write_report`): the files it owns, and only those."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

from abm.errors import DataError, OutputError
from abm.experiments.arm_records import arm_records, is_arm_records
from abm.experiments.report.numbers import Cells
from abm.experiments.report.outcomes import collect, kept_run_summaries
from abm.experiments.report.texts import Written, compose, newest_edition
from abm.experiments.spec import ExperimentSpec
from abm.experiments.state import Layout
from abm.files import is_inside


def replace_block(text: str, name: str, body: str, source: str = "README") -> str:
    """``text`` with what stands between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->`` replaced by ``body``."""
    return replace_between(text, f"<!-- {name}:start -->", f"<!-- {name}:end -->", body, source)


def replace_between(text: str, start: str, end: str, body: str, source: str) -> str:
    """``text`` with what stands between the markers ``start`` and ``end`` replaced by a newline and ``body``.

    Raises:
        DataError: ``text`` (the file ``source``) lacks a marker.
    """
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


LOSS_COLUMNS = ("step", "total", "translation", "rotation", "gripper", "zoom_translation")


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
    """Write every generated file of the report (see the module docstring; the README's blocks and the zoo's
    README only once the spec's README gate is open, :mod:`abm.experiments.report.gate`); returns their texts."""
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
        if spec.report.zoo_readme and not written.waits and newest_edition(spec, written.zoo):
            _write(layout.zoo / "README.md", written.zoo_readme)
    if spec.report.records:
        _write(layout.root / spec.report.records, json.dumps(written.records, indent=1) + "\n")
    if spec.report.arm_records:
        records_of_arms = arm_records(spec, outcomes.cells, outcomes.summaries, outcomes.loops)
        _write(layout.root / spec.report.arm_records, json.dumps(records_of_arms, indent=1) + "\n")
    if spec.report.document:
        _write(layout.root / spec.report.document, written.document)
    if spec.report.readme and not written.waits:  # the README gate is open (or there is none)
        readme = layout.root / spec.report.readme
        text = replace_block(readme.read_text(), spec.report.block, written.block, spec.report.readme)
        for name, body in written.blocks.items():
            text = replace_block(text, name, body, spec.report.readme)
        _write(readme, text)
    return written
