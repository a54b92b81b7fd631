"""Result figures: success-rate bar charts (seen / unseen per task and method, error bars over repeats) and
training curves (losses from ``log.csv``, keyframe error against training steps).

Used by ``abm train`` (``RUN/training_curve.png``), ``abm eval`` (``success.png`` and ``training.png`` beside
``results.md`` and in ``report.html``), ``abm quickstart`` (its report's ``training_curves.png``) and the
experiment reports (:mod:`abm.experiments.report`: the README images). :func:`loss_curves` is the one
training-curve plotter (:func:`run_loss_curves` reads the runs' logs for it). Every function takes plain data
(the dicts of ``results.json``, or :class:`~abm.evaluation.results.SuccessRate`, ``log.csv`` rows) and writes
a PNG with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn
    from matplotlib.figure import Figure

SPLIT_ORDER = ("seen", "unseen", "compositional")


def _pyplot() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _as_dict(rate: Any) -> dict[str, Any]:
    if isinstance(rate, Mapping):
        return dict(rate)
    return {"method": rate.method, "task": rate.task, "split": rate.split, "per_repeat": list(rate.per_repeat),
            "episodes": rate.episodes, "mean": rate.mean, "std": rate.std}


def _save(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, metadata={"Software": None})  # no version string: reruns give the same bytes
    _pyplot().close(fig)
    return path


def success_chart(rates: Sequence[Any], path: str | Path, title: str = "", methods: Sequence[str] | None = None,
                  average: bool = True) -> Path:
    """Grouped bars of success (%) per task, one panel per split (seen, unseen, ...), one bar per method.

    Args:
        rates: ``results.json`` entries (method, task, split, per_repeat, mean, std) or ``SuccessRate`` s.
        methods: bar order (default: order of first appearance).
        average: add an "avg" group (mean over the tasks of each method; no error bar).

    Error bars are the standard deviation over repeats (none for a single repeat); each bar is labelled
    with its mean.
    """
    plt = _pyplot()
    items = [_as_dict(r) for r in rates]
    if not items:
        raise ValueError("no success rates to plot")
    splits = [s for s in SPLIT_ORDER if any(r["split"] == s for r in items)]
    splits += sorted({r["split"] for r in items} - set(splits))
    methods = list(methods or dict.fromkeys(r["method"] for r in items))
    tasks = list(dict.fromkeys(r["task"] for r in items))
    cell = {(r["method"], r["task"], r["split"]): r for r in items}
    groups = tasks + (["avg"] if average and len(tasks) > 1 else [])
    colors = plt.get_cmap("tab10")
    panel = min(8.0, max(4.5, 1.0 + 0.25 * len(groups) * len(methods)))  # inches per split
    fig, axes = plt.subplots(1, len(splits), figsize=(panel * len(splits), 3.6), sharey=True, squeeze=False)
    width = 0.8 / max(1, len(methods))
    for ax, split in zip(axes[0], splits, strict=True):
        x = np.arange(len(groups))
        for i, method in enumerate(methods):
            means, errs = [], []
            for g in groups:
                if g == "avg":
                    vals = [cell[(method, t, split)]["mean"] for t in tasks if (method, t, split) in cell]
                    means.append(float(np.mean(vals)) if vals else np.nan)
                    errs.append(0.0)
                    continue
                r = cell.get((method, g, split))
                means.append(r["mean"] if r else np.nan)
                errs.append(r["std"] if r and len(r.get("per_repeat", [])) > 1 else 0.0)
            pos = x - 0.4 + width * (i + 0.5)
            err = np.array(errs)
            bars = ax.bar(pos, means, width, yerr=np.where(err > 0, err, np.nan), capsize=3, color=colors(i % 10),
                          label=method, error_kw={"elinewidth": 1})
            for b, m, e in zip(bars, means, err, strict=True):
                if np.isfinite(m):
                    ax.text(b.get_x() + b.get_width() / 2, m + e + 1.5, f"{m:.0f}", ha="center", va="bottom",
                            fontsize=7 if len(methods) < 5 else 6)
        ax.set_xticks(x, [g.replace("_", "_\n") if len(g) > 12 else g for g in groups], fontsize=8)
        ax.set_title(f"{split} objects" if split in ("seen", "unseen") else split)
        ax.set_ylim(0, 115)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("success (%)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=min(len(methods), 6), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 1.0))
    if title:
        fig.suptitle(title, y=0.9, fontsize=9, color="0.3")
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    return _save(fig, path)


def read_log(run: str | Path) -> list[dict[str, str]]:
    """The rows of a training run's ``log.csv`` (empty when there is none)."""
    log = Path(run) / "log.csv"
    if not log.is_file():
        return []
    with log.open() as f:
        return list(csv.DictReader(f))


def run_loss_curves(runs: Mapping[str, str | Path], path: str | Path) -> Path | None:
    """:func:`loss_curves` of training runs (label -> run folder) that have a ``log.csv``; ``None`` if none has."""
    logs = {label: rows for label, run in runs.items() if (rows := read_log(run))}
    return loss_curves(logs, path) if logs else None


def loss_curves(runs: Mapping[str, Sequence[Mapping[str, Any]]], path: str | Path,
                heads: Sequence[str] = ("total", "translation", "rotation", "gripper")) -> Path:
    """Training losses against steps, one panel per loss head, one line per run (label -> ``log.csv`` rows with
    ``step`` and the head columns). Log scale; rows without a value are skipped. A run that logged a validation
    loss (``val_total``: ``abm train --val-data``) has it beside its total training loss, dashed with dots."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(heads), figsize=(3.6 * len(heads), 3.0), squeeze=False)
    for label, rows in runs.items():
        for ax, head in zip(axes[0], heads, strict=True):
            pts = [(int(float(r["step"])), float(r[head])) for r in rows if r.get(head) not in (None, "")]
            colour = ax.plot(*zip(*pts, strict=True), label=label, linewidth=1.2)[0].get_color() if pts else None
            held_out = [(int(float(r["step"])), float(r["val_total"])) for r in rows
                        if head == "total" and r.get("val_total") not in (None, "")]
            if held_out:
                ax.plot(*zip(*held_out, strict=True), "o--", color=colour, label=f"{label} validation",
                        linewidth=1.0, markersize=3)
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    for ax, head in zip(axes[0], heads, strict=True):
        ax.set_title(f"{head} loss", fontsize=9)
        ax.set_xlabel("step")
        ax.set_yscale("log")
        low, high = ax.get_ylim()
        ax.yaxis.set_major_formatter(FormatStrFormatter("%.3g"))  # plain numbers, also on short ranges
        # minor ticks labelled only on a short range (over two decades their labels would overlap)
        ax.yaxis.set_minor_formatter(FormatStrFormatter("%.3g") if high < 100 * low else NullFormatter())
        ax.tick_params(axis="y", which="both", labelsize=7)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def keyframe_error_curve(summary: Sequence[Mapping[str, Any]], path: str | Path, kind: str = "grasp",
                         split: str = "seen", final_step: int | None = None) -> Path:
    """Median keyframe position error (cm) against training steps, one line per method, averaged over tasks.

    ``summary`` rows come from ``benchmarks/keyframe_accuracy.py`` (``method`` is ``NAME`` for the final
    checkpoint and ``NAME@STEP`` for intermediate ones; ``position_cm_median``); the final checkpoint is
    drawn at ``final_step`` (default: one step interval after the last intermediate one).
    """
    plt = _pyplot()
    curves: dict[str, dict[int | None, list[float]]] = {}
    for row in summary:
        if row.get("kind") != kind or row.get("split") != split:
            continue
        name, _, step = str(row["method"]).partition("@")
        curves.setdefault(name, {}).setdefault(int(step) if step else None, []).append(
            float(row["position_cm_median"]))
    if not curves:
        raise ValueError(f"no {kind} keyframes on {split} objects in the summary")
    fig, ax = plt.subplots(figsize=(5.4, 3.3))
    for name, by_step in curves.items():
        steps = sorted(s for s in by_step if s is not None)
        last = final_step or (steps[-1] + (steps[-1] - steps[-2] if len(steps) > 1 else steps[-1]) if steps else 1)
        pts = [(s, float(np.mean(by_step[s]))) for s in steps]
        if None in by_step:
            pts.append((last, float(np.mean(by_step[None]))))
        ax.plot(*zip(*pts, strict=True), marker="o", label=name)
    ax.set_xlabel("training step")
    ax.set_ylabel(f"{kind} position error (cm, median)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{kind} keyframe error, {split} objects (mean over tasks)", fontsize=9)
    fig.tight_layout()
    return _save(fig, path)
