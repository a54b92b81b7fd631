"""The ``targets`` report section: each target checked against each row run's measurements."""

from __future__ import annotations

from collections.abc import Mapping

from abm.experiments.arm_records import loop_share
from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import kind_medians
from abm.experiments.report.numbers import pct, ratio
from abm.experiments.report.sections.seeds import seed_spread
from abm.experiments.spec import SPREAD_CHECK, Section, TargetCheck


def verdict(text: str, ok: bool | None, value: str) -> str:
    return f"{text}: not evaluated yet" if ok is None else f"{text}: {'met' if ok else 'not met'} ({value})"


def shortfall(missed_by: float, split: str, spread: Mapping[str, float], digits: int) -> str:
    """``; N short, within the seed spread of S points`` when a point target is missed by no more than the
    measured seed spread of its split (the miss is then not a measured difference), else ""."""
    if split not in spread or missed_by > spread[split]:
        return ""
    return f"; {missed_by:.{digits}f} short, within the seed spread of {spread[split]:.{digits}f} points"


def checked(ctx: Context, section: Section) -> tuple[list[str], dict[str, list[str]]]:
    """The verdicts of a ``targets`` section, one ``RUN: check: verdict; ...`` per row run after one ``check:
    verdict`` per ``exceeds_spread`` check (of the table, :func:`exceeds_spread`), and the texts of the checks each
    run misses (measured, not asserted; with ``explain``, a target in points missed by no more than the report's
    seed spread, :func:`seed_spread`, says so)."""
    parts = []
    digits = section.digits
    missed: dict[str, list[str]] = {}
    spread = seed_spread(ctx) if section.explain else {}
    for check in (c for c in section.checks if c.kind == SPREAD_CHECK):  # of the section's table, not of a row
        parts.append(exceeds_spread(ctx, check, digits))
    for run in section.runs:
        checks = []
        for check in section.checks:
            if check.run and check.run != run or check.kind == SPREAD_CHECK:
                continue
            value = ctx.average(run, check.split)
            ok: bool | None
            if check.kind == "at_least":
                ok = None if value is None else value >= check.value
                shown = pct(value, digits)
                if ok is False and value is not None:
                    shown += shortfall(check.value - value, check.split, spread, digits)
            elif check.kind == "ratio":
                seen = ctx.average(run, "seen")
                ok = None if seen is None or value is None or not seen else value / seen >= check.value
                shown = ratio(seen, value)
            elif check.kind in ("keyframe_cm", "keyframe_deg", "loops"):
                ok, shown = at_most(ctx, run, check)
            else:
                base = ctx.average(check.base, check.split)
                if check.kind == "beats":
                    ok = None if value is None or base is None else value >= base + check.value
                else:
                    ok = None if value is None or base is None else value < check.value * base
                shown = f"{pct(value, digits)} vs {pct(base, digits)}"
                if check.kind == "beats" and ok is False and value is not None and base is not None:
                    shown += shortfall(base + check.value - value, check.split, spread, digits)
            checks.append(verdict(check.text, ok, shown))
            if ok is False:
                missed.setdefault(run, []).append(check.text)
        if checks:
            parts.append(f"{run}: " + "; ".join(checks))
    return parts, missed


def exceeds_spread(ctx: Context, check: TargetCheck, digits: int) -> str:
    """An ``exceeds_spread`` check (:class:`TargetCheck`) as the report states it: met when every named difference
    between two rows' split averages exceeds table ``of_table``'s seed spread on the split (:func:`seed_spread`) by
    more than ``value`` points, not met with every difference beside the spread otherwise, not measured yet while
    the spread or a row's average is missing (naming what is missing)."""
    spread = seed_spread(ctx, check.of_table).get(check.split)
    averages = {r: ctx.average(r, check.split) for pair in check.pairs for r in pair}
    missing = [r for r, v in averages.items() if v is None]
    if spread is None or missing:
        lacking = ([f"Table {check.of_table}'s seed spread"] if spread is None else []) + [f"{r}'s average"
                                                                                          for r in missing]
        return f"{check.text}: not measured yet (missing on {check.split}: {', '.join(lacking)})"
    values = {r: v for r, v in averages.items() if v is not None}
    bar = spread + check.value
    shown, ok = [], True
    for a, b in check.pairs:
        difference = abs(values[a] - values[b])
        ok = ok and difference > bar
        shown.append(f"{a} vs {b} {difference:.{digits}f}{'' if difference > bar else ' (within)'}")
    limit = f"seed spread {spread:.{digits}f}" + (f" + {check.value:g}" if check.value else "")
    return verdict(check.text, ok, f"{limit} points; " + ", ".join(shown))


def at_most(ctx: Context, run: str, check: TargetCheck) -> tuple[bool | None, str]:
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


def write(ctx: Context, section: Section) -> list[str]:
    """Each target checked against the averages of each row run (:func:`checked`), as one paragraph."""
    parts, _ = checked(ctx, section)
    return [f"{section.text}: " + ". ".join(parts) + "."]
