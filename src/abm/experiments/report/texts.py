"""The texts of a report from its outcomes (:func:`compose`): each section's paragraphs by its kind's writer
(:data:`abm.experiments.report.kinds.SECTIONS`), the provenance line, links, records and the zoo's README."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.experiments.report.context import Context
from abm.experiments.report.gate import waits
from abm.experiments.report.kinds import SECTIONS
from abm.experiments.report.numbers import Cells, successes, table_head, table_row
from abm.experiments.report.outcomes import Outcomes, mark_compared
from abm.experiments.spec import SPECS, ExperimentSpec, Section
from abm.experiments.state import Layout
from abm.registry import resolve
from abm.zoo import edition


def reproduce(ctx: Context) -> str:
    """The line under a block's tables: the command that reproduces them."""
    name = ctx.spec.name if ctx.spec.path.resolve().parent == SPECS else spec_name(ctx.spec, ctx.layout)
    return (f"Reproduce: `abm experiment run {name}` (every stage, resuming from the kept outcomes; "
            f"`abm experiment run {name} --stages report` rewrites the tables above from them alone).")


def write_section(ctx: Context, section: Section) -> list[str]:
    """The paragraphs of one section, by its kind's writer (:data:`~abm.experiments.report.kinds.SECTIONS`).

    Raises:
        UnknownNameError: no section kind has that name (the message lists them).
    """
    writer: Callable[[Context, Section], list[str]] = resolve(SECTIONS[section.kind].writer)
    return writer(ctx, section)


def blocks(ctx: Context, sections: Sequence[Section], into: str = "") -> list[str]:
    """The paragraphs of ``sections``, in order (empty ones and repeats of an earlier one left out), then, when
    one of them wrote a table, :func:`reproduce`'s line. ``into`` (``readme`` or ``document``) leaves out the
    sections meant only for the other (``Section.only``)."""
    out: list[str] = []
    tables = False
    for section in sections:
        if into and section.only and section.only != into:
            continue
        written = [b for b in write_section(ctx, section) if b and b not in out]
        out += written
        if SECTIONS[section.kind].reproduce:
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
    where = f"[{kept}/]({kept}/)" if layout.kept.is_dir() else f"{kept}/ (nothing kept yet)"  # no dead link
    return f"Written by `abm experiment run {spec.name}` ([{source}]({source})) from the {what} kept in {where}{tail}."


_LINK = re.compile(r"\]\(([^)\s]+)\)")


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
    """The texts of one report (what :func:`write_report` writes); ``waits``: what the README gate
    (``report.readme_when``) waits for before the README's blocks and the zoo's README are written ("": open, or
    no gate; :func:`abm.experiments.report.gate.waits`)."""

    summary: str
    document: str
    block: str
    blocks: dict[str, str]
    records: list[dict[str, Any]]
    zoo: list[dict[str, Any]] | None
    zoo_readme: str
    waits: str = ""


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
             *table_head(["name", *(["edition"] if editions else []), "what", "method", "grounder", "steps",
                          "train min", "MB", "sha256"])]
    for e in entries:
        shown = [str(edition(dict(e)))] if editions and e.get("method") != "clip" else ["–"] if editions else []
        lines.append(table_row([e["name"], *shown, e.get("label") or "–", e["method"], str(e.get("grounder", "–")),
                                str(e.get("steps", "–")), str(e.get("train_minutes", "–")),
                                f"{e['size_bytes'] / 1e6:.1f}", f"`{e['sha256'][:16]}…`"]))
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
    waiting = waits(ctx)
    zoo = (outcomes.index if outcomes.index is not None else outcomes.entries) if layout.zoo is not None else None
    if zoo is not None:  # abm zoo eval takes a gated edition's models once its gate is open
        zoo = mark_compared(spec, zoo, gate_open=not waiting)
    return Written(summary=summary, document=document, block=block, blocks=extra,
                   records=records(spec, outcomes.cells),
                   zoo=zoo, zoo_readme=zoo_readme(spec, layout, zoo) if zoo is not None else "", waits=waiting)
