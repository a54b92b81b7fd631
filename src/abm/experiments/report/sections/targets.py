"""The ``targets`` report section: each target checked against each row run's measurements."""

from __future__ import annotations

from collections.abc import Mapping

from abm.experiments.arm_records import loop_share
from abm.experiments.report.context import Context
from abm.experiments.report.keyframes import kind_medians
from abm.experiments.report.numbers import pct, ratio
from abm.experiments.report.sections.seeds import seed_spread
from abm.experiments.spec import Section, TargetCheck


def verdict(text: str, ok: bool | None, value: str) -> str:
    return f"{text}: not evaluated yet" if ok is None else f"{text}: {'met' if ok else 'not met'} ({value})"


def shortfall(missed_by: float, split: str, spread: Mapping[str, float], digits: int) -> str:
    """``; N short, within the seed spread of S points`` when a point target is missed by no more than the
    measured seed spread of its split (the miss is then not a measured difference), else ""."""
    if split not in spread or missed_by > spread[split]:
        return ""
    return f"; {missed_by:.{digits}f} short, within the seed spread of {spread[split]:.{digits}f} points"


def checked(ctx: Context, section: Section) -> tuple[list[str], dict[str, list[str]]]:
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
