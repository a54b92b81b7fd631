"""A self-contained HTML page per evaluation: success table, failure reasons, rollout GIFs and heatmap overlays.

No scripts, fonts or styles are fetched from anywhere (it works offline); GIFs are linked by relative
path, so the page works wherever the evaluation folder is copied.
"""

from __future__ import annotations

import html
import os
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path

from abm.evaluation.results import FAILURES, EpisodeOutcome, aggregate, subgoal_rates

_STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 4px 10px; text-align: right; }
th:first-child, td:first-child { text-align: left; }
.ok { color: #176b1f; } .fail { color: #a11; }
.gallery { display: flex; gap: 2em; flex-wrap: wrap; }
figure { margin: 0.5em; display: inline-block; text-align: center; }
figcaption { font-size: 0.85em; }
"""


def gif_name(outcome: EpisodeOutcome) -> str:
    """File name of the rollout GIF ``abm eval --gifs`` writes for an outcome (repeat 0 only)."""
    return f"{outcome.method}_{outcome.task}_{outcome.split}_{outcome.episode:03d}.gif".replace(" ", "_")


def views_name(outcome: EpisodeOutcome) -> str:
    """File name of the heatmap overlays written beside the GIF (one row of five views per step)."""
    return gif_name(outcome).removesuffix(".gif") + "_views.png"


def _said(outcome: EpisodeOutcome) -> str:
    """The caption's instruction and target line (empty for outcomes recorded without them)."""
    if not outcome.instruction:
        return ""
    target = f" (target: {html.escape(outcome.target)})" if outcome.target else ""
    return f"<br><i>{html.escape(outcome.instruction)}</i>{target}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def write_html_report(outcomes: Sequence[EpisodeOutcome], path: str | Path, gif_dir: str | Path | None = None,
                      title: str = "abm evaluation") -> Path:
    """Write the report for ``outcomes`` to ``path`` and return it.

    Args:
        outcomes: the rollouts (any methods, tasks and splits).
        path: the HTML file.
        gif_dir: folder holding the rollout GIFs (named by :func:`gif_name`); missing ones are skipped.
        title: page title.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>"]

    parts.append("<h2>Success rate (%)</h2>")
    rows = [[html.escape(r.method), html.escape(r.task), html.escape(r.split),
             f"{r.mean:.1f}" + (f" ± {r.std:.1f}" if len(r.per_repeat) > 1 else ""),  # no "± 0.0" for one repeat
             str(r.episodes), str(r.errors)] for r in aggregate(outcomes)]
    parts.append(_table(["method", "task", "split", "success", "episodes", "crashed"], rows))
    for name, alt in (("success.png", "success rate per task, split and method; error bars: std over repeats"),
                      ("training.png", "training losses of the evaluated runs")):
        if (path.parent / name).is_file():
            parts.append(f"<p><img src='{name}' alt='{alt}' style='max-width: 100%'></p>")

    sub = subgoal_rates(outcomes)
    if sub:
        parts.append("<h2>Success per sub-goal (%)</h2><p>Two-target instructions: sub-goal 1 = X grasped, "
                     "sub-goal 2 = X placed in Y (the task's success).</p>")
        rows = [[html.escape(m), html.escape(t), html.escape(s), *[f"{r:.1f}" for r in rates], str(n)]
                for m, t, s, rates, n in sub]
        parts.append(_table(["method", "task", "split", "sub-goal 1", "sub-goal 2", "episodes"], rows))

    parts.append("<h2>Why episodes failed</h2>")
    counts: dict[tuple[str, str, str], Counter[str]] = defaultdict(Counter)
    for o in outcomes:
        if not o.success:
            counts[(o.method, o.task, o.split)][o.failure or "unknown"] += 1
    reasons = [*FAILURES, "unknown"]
    used = [r for r in reasons if any(c[r] for c in counts.values())] or list(FAILURES)
    rows = [[html.escape(m), html.escape(t), html.escape(s), *[str(c[r]) for r in used]]
            for (m, t, s), c in sorted(counts.items())]
    parts.append(_table(["method", "task", "split", *used], rows) if rows else "<p>No failed episodes.</p>")

    by_target: dict[tuple[str, str, str, str], list[EpisodeOutcome]] = defaultdict(list)
    for o in outcomes:
        if o.target:
            by_target[(o.method, o.task, o.split, o.target)].append(o)
    if by_target:
        parts.append("<h2>Success per target object</h2><p>Which objects the failures come from (the "
                     "instruction's target, from outcomes.jsonl).</p>")
        rows = [[html.escape(m), html.escape(t), html.escape(s), html.escape(target),
                 f"{sum(o.success for o in items)}/{len(items)}"]
                for (m, t, s, target), items in sorted(by_target.items())]
        parts.append(_table(["method", "task", "split", "target", "successes / episodes"], rows))

    if gif_dir is not None:
        gif_dir = Path(gif_dir)
        parts.append("<h2>Rollouts</h2><p>Front camera; each frame shows the keyframe predicted from it. Below "
                     "each GIF: the policy's five virtual views per step, the target tinted cyan, the mask "
                     "channel's centre ring in magenta and the predicted translation heatmap (jet).</p>")
        by_task: dict[tuple[str, str], list[EpisodeOutcome]] = defaultdict(list)
        for o in sorted(outcomes, key=lambda o: (o.task, o.split, o.method, o.episode)):
            if o.repeat == 0 and (gif_dir / gif_name(o)).is_file():
                by_task[(o.task, o.split)].append(o)
        for (task, split), items in by_task.items():
            parts.append(f"<h3>{html.escape(task)} ({html.escape(split)})</h3><div class='gallery'>")
            for label, keep, css in (("successes", True, "ok"), ("failures", False, "fail")):
                figs = []
                for o in (o for o in items if o.success == keep):
                    src = os.path.relpath(gif_dir / gif_name(o), path.parent)
                    note = "success" if o.success else (o.failure or "failed")
                    views = gif_dir / views_name(o)
                    overlay = ""
                    if views.is_file():
                        rel = html.escape(os.path.relpath(views, path.parent))
                        overlay = (f"<br><a href='{rel}'><img src='{rel}' width='384' "
                                   "alt='virtual views with mask and heatmaps'></a>")
                    figs.append(f"<figure><img src='{html.escape(src)}' width='192'>{overlay}"
                                f"<figcaption class='{css}'>{html.escape(o.method)} · episode {o.episode} · "
                                f"{html.escape(note)}{_said(o)}</figcaption></figure>")
                parts.append(f"<div><h4>{label}</h4>{''.join(figs) or '<p>none</p>'}</div>")
            parts.append("</div>")
    parts.append("</body></html>")
    path.write_text("\n".join(parts))
    return path
