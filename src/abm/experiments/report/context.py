"""What every section writer sees (:class:`Context`), and the lookups several sections share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from abm.errors import ConfigError
from abm.experiments.report.numbers import Cells, average, pct, spread_note, standard_error
from abm.experiments.report.outcomes import Outcomes
from abm.experiments.spec import ExperimentSpec, GrounderVariant, Section
from abm.experiments.state import Layout


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


def paper_cells(section: Section, run: str, count: int) -> list[str]:
    values = section.paper.get(run)
    return [f"{v}" for v in values] if values else [""] * count


def table_section(ctx: Context, number: int | None) -> Section:
    for s in (*ctx.spec.report.summary, *ctx.spec.report.details):
        if s.table == number:
            return s
    raise ConfigError(f"{ctx.spec.path}: no report table {number}")


def evaluated(ctx: Context, name: str) -> bool:
    return any(run == name for run, _, _ in ctx.cells)
