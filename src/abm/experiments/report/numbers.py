"""The numbers of a report's tables: a cell's success, split averages and their standard error, and how they
are shown (``–`` until evaluated)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

Rate = Mapping[str, Any]  #: one evaluation cell (a record of ``abm eval``'s results.json)


Cells = dict[tuple[str, str, str], dict[str, Any]]  #: (run, task, split) -> its rate


_WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")


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
    return (f"± in a cell: the standard deviation of the task's success over the {number(repeats)} repeats; ± "
            f"after an average: its standard error, the sample standard deviation over the repeats of the "
            f"repeat-wise average over the tasks, divided by √{repeats}.")


def pct(v: float | None, digits: int = 1) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def ratio(seen: float | None, unseen: float | None) -> str:
    return "–" if seen is None or unseen is None or seen <= 0 else f"{unseen / seen:.2f}"


def number(n: int) -> str:
    return _WORDS[n] if 0 <= n < len(_WORDS) else str(n)


def table_row(values: Sequence[str]) -> str:
    return "| " + " | ".join(values) + " |"


def table_head(values: Sequence[str]) -> list[str]:
    return [table_row(values), "|---" * len(values) + "|"]
