"""Write the CLIP-grounder result of ``scripts/clip_grounder.sh`` (never typed by hand).

Reads ``OUT/eval_seen/results.json`` and ``OUT/eval_unseen/results.json`` (five runs evaluated together:
abm_oracle, abm_clip, rvt_hash, rvt_clip, ifd_clip), ``OUT/eval_SPLIT_oracle_trained_clip/results.json``
(abm_oracle grounded by CLIP), the training logs ``OUT/RUN/log.csv`` and, when present, the mask-quality
JSON of ``benchmarks/clip_quality.py``; writes the markdown to ``--report`` (default
``docs/results/clip_grounder.md``), keeps the JSON it was built from beside it
(``docs/results/clip_grounder/``) and replaces the block between ``<!-- clip-grounder:start -->`` and
``<!-- clip-grounder:end -->`` in the README when it has one.

The success bar chart (``abm.evaluation.plots``; one bar per table row) goes to ``docs/images/results/``,
drawn from the kept JSON only, so ``--figures-only`` redraws it from what is committed.

With the runs' training logs at hand it also keeps compact loss curves (``training_RUN.csv``) and draws them.

Usage: python benchmarks/clip_grounder_report.py OUT [--clip models/benchmark-clip] [--quality runs/clip_quality.json]
       python benchmarks/clip_grounder_report.py --figures-only
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path

from seen_unseen_report import (
    _cell,
    _eval_max_steps,
    _load,
    _machine,
    _training,
    add_figure_arguments,
    figure_markdown,
    keep_training_log,
    redraw_only,
)

START, END = "<!-- clip-grounder:start -->", "<!-- clip-grounder:end -->"
#: run folder -> (variant, what grounds the target / carries the instruction), in table order
RUNS: dict[str, tuple[str, str]] = {
    "abm_oracle": ("abm", "mask from the simulator's segmentation (oracle, upper bound)"),
    "abm_clip": ("abm", "mask from the benchmark CLIP (the default grounder: 3-D proposals scored by CLIP)"),
    "rvt_hash": ("rvt", "instruction through the weight-free hash encoder (no mask)"),
    "rvt_clip": ("rvt", "instruction through the benchmark CLIP's text encoder (no mask)"),
    "ifd_clip": ("ifd", "benchmark-CLIP point features in the views + CLIP text (no mask)"),
}
#: evaluations of a run with another grounder: row name -> (run folder, eval folder suffix, variant, description)
SWAPPED: dict[str, tuple[str, str, str, str]] = {
    "abm_oracle → CLIP": ("abm_oracle", "oracle_trained_clip", "abm",
                          "trained on oracle masks, grounded by the benchmark CLIP at evaluation"),
}


def run_label(name: str, rates: Sequence[Mapping]) -> str | None:
    """The label ``abm eval`` gave run folder ``name`` (``variant`` alone when unique, else ``variant (name)``)."""
    variant = RUNS[name][0]
    for label in (f"{variant} ({name})", variant):
        if any(r["method"] == label for r in rates):
            return label
    return None


def stored_rates(store: Path) -> list[dict]:
    """The rates kept under ``store`` (``results_SPLIT[_SUFFIX].json``), each labelled with its table row."""
    rates = _load(store / "results_seen.json") + _load(store / "results_unseen.json")
    labels = {run_label(name, rates): name for name in RUNS}
    out = [{**r, "method": labels[r["method"]]} for r in rates if r["method"] in labels]
    for row, (_, suffix, _, _) in SWAPPED.items():
        for split in ("seen", "unseen"):
            path = store / f"results_{split}_{suffix}.json"
            if path.is_file():
                out += [{**r, "method": row} for r in json.loads(path.read_text())]
    return out


def figures(store: Path, images: Path) -> list[tuple[Path, str]]:
    """The success chart of every table row, from the kept JSON; ``(png, alt text)`` pairs."""
    from abm.evaluation.plots import loss_curves, success_chart

    rows = [*RUNS, *SWAPPED]
    rates = stored_rates(store)
    methods = [r for r in rows if any(x["method"] == r for x in rates)]
    out = [(success_chart(rates, images / "clip_grounder_success.png", methods=methods),
            "rollout success of each run per task, seen and unseen objects; error bars: std over repeats")]
    logs = {name: list(csv.DictReader((store / f"training_{name}.csv").open())) for name in RUNS
            if (store / f"training_{name}.csv").is_file()}
    if logs:
        out.append((loss_curves(logs, images / "clip_grounder_losses.png"), "training losses of the runs"))
    return out


def _mean(values: Sequence[float]) -> float:
    return sum(values) / len(values) if values else float("nan")


def load_rates(out: Path) -> list[dict]:
    """Every evaluation of ``out``: the joint one of the five runs, then the swapped-grounder ones (relabelled
    with their row names)."""
    rates = _load(out / "eval_seen" / "results.json") + _load(out / "eval_unseen" / "results.json")
    for row, (_, suffix, _, _) in SWAPPED.items():
        for split in ("seen", "unseen"):
            path = out / f"eval_{split}_{suffix}" / "results.json"
            if path.is_file():
                rates += [{**r, "method": row} for r in json.loads(path.read_text())]
    return rates


def success_table(rates: Sequence[Mapping]) -> tuple[str, dict[str, dict[str, float]]]:
    """Markdown table (one row per run or swapped-grounder evaluation) and the seen/unseen averages per row."""
    tasks = sorted({r["task"] for r in rates})
    head = ["run", "method", "target from"] + [f"{t} {s}" for s in ("seen", "unseen") for t in tasks] + [
        "seen avg", "unseen avg", "unseen / seen"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    averages: dict[str, dict[str, float]] = {}
    rows = [(name, variant, what, run_label(name, rates)) for name, (variant, what) in RUNS.items()]
    rows += [(row, variant, what, row) for row, (_, _, variant, what) in SWAPPED.items()]
    for name, variant, what, label in rows:
        if label is None or not any(r["method"] == label for r in rates):
            continue
        cell = {(r["task"], r["split"]): r for r in rates if r["method"] == label}
        row = [name, variant, what]
        avg = {}
        for s in ("seen", "unseen"):
            row += [_cell(cell.get((t, s))) for t in tasks]
            avg[s] = _mean([cell[(t, s)]["mean"] for t in tasks if (t, s) in cell])
        ratio = avg["unseen"] / avg["seen"] if avg["seen"] > 0 else float("nan")
        row += [f"{avg['seen']:.0f}", f"{avg['unseen']:.0f}", f"{ratio:.2f}"]
        averages[name] = avg
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines), averages


def mask_quality(quality: Mapping, tasks: Sequence[str], normalization: str, threshold: float) -> str:
    """The trained CLIP's mask-field quality on these tasks' scenes at the grounder's setting."""
    rows = [c for c in quality.get("mask_cases", []) if c["model"] == "trained" and c["task"] in tasks
            and c["normalization"] == normalization and math.isclose(c["threshold"], threshold)]
    if not rows:
        return ""
    out = ["| task | split | scenes | mask IoU | precision | recall | hit (mask centre on the target) "
           "| top-1 point on the target |", "|---|---|---|---|---|---|---|---|"]
    for t in tasks:
        for s in ("seen", "unseen"):
            cs = [c for c in rows if c["task"] == t and c["split"] == s]
            if cs:
                mean = {k: _mean([c[k] for c in cs]) for k in ("iou", "precision", "recall", "hit", "top1")}
                out.append(f"| {t} | {s} | {len(cs)} | {mean['iou']:.2f} | {mean['precision']:.2f} | "
                           f"{mean['recall']:.2f} | {100 * mean['hit']:.0f} % | {100 * mean['top1']:.0f} % |")
    return "\n".join(out)


def grounding_quality(quality: Mapping, tasks: Sequence[str], config: str) -> str:
    """Mask quality of grounding configuration ``config`` on these tasks' scenes, from the records of
    ``benchmarks/grounding_quality.py`` (``docs/results/grounding_quality.json``)."""
    rows = [r for r in quality.get("records", []) if r["config"] == config and r["task"] in tasks]
    if not rows:
        return ""
    out = ["| task | split | scenes | mask IoU | hit rate | top-1 point on the target |", "|---|---|---|---|---|---|"]
    for t in tasks:
        for s in ("seen", "unseen"):
            for r in (r for r in rows if r["task"] == t and r["split"] == s):
                out.append(f"| {t} | {s} | {r['n']} | {r['iou']:.2f} | {100 * r['hit_rate']:.0f} % | "
                           f"{100 * r['top1']:.0f} % |")
    return "\n".join(out)


def _grounder_setting(config: Mapping) -> tuple[str, float]:
    """Normalisation and threshold the abm_clip run grounded with (its stored grounder options)."""
    from abm.grounding.mask_field import DEFAULT_NORMALIZATION, DEFAULT_THRESHOLD

    options = config["train"].get("grounder_options") or {}
    return options.get("normalization", DEFAULT_NORMALIZATION), float(options.get("threshold", DEFAULT_THRESHOLD))


def report(out: Path, clip: Path, command: str, quality: Mapping | None = None, figures_md: str = "",
           grounding: Mapping | None = None, grounding_config: str = "") -> tuple[str, str]:
    """The whole report and its summary for the README (everything but the mask-quality tables).

    ``grounding`` is the JSON of ``benchmarks/grounding_quality.py``; its records of ``grounding_config``
    (the configuration the abm_clip run grounded with) on these tasks go into the full report."""
    rates = load_rates(out)
    tasks = sorted({r["task"] for r in rates})
    table, avg = success_table(rates)
    config = json.loads((out / "abm_clip" / "config.json").read_text())
    train = {name: _training(out / name) for name in RUNS if (out / name / "log.csv").is_file()}
    repeats = max(len(r["per_repeat"]) for r in rates)
    episodes = max(r["episodes"] for r in rates)
    clip_info = json.loads((clip / "abm_clip.json").read_text()) if (clip / "abm_clip.json").is_file() else {}
    arch = clip_info.get("recipe", {}).get("arch", {}).get("vision", {})
    policy = config["policy"]
    lines = [
        f"Written by `benchmarks/clip_grounder_report.py` from the evaluation JSON of `{command}` "
        "(kept in [clip_grounder/](clip_grounder/)).",
        "",
        f"Machine: {_machine()}. CLIP: the benchmark CLIP in `{clip}` (`abm clip train`: a "
        + (f"{arch.get('num_hidden_layers')}-layer, {arch.get('hidden_size')}-wide ViT at "
           f"{arch.get('image_size')}² " if arch else "")
        + "trained on simulator renders of every catalog object with their names, never on demonstrations; "
        "see docs/grounding.md). Policies: `small` preset at "
        f"{policy['resolution']}² views over a {policy['workspace_size']} m cube, "
        f"{config['train']['steps']} steps of batch {config['train']['batch']}, {config['train']['optimizer']} "
        f"lr {config['train']['lr']}, trained two at a time with one thread each (the odd one out alone with two; "
        + ", ".join(f"{n} {t['elapsed_min']:.0f} min" for n, t in train.items())
        + f") on the same seen demonstrations. Evaluation: {episodes // repeats} seeded episodes per task, "
        f"split and repeat, {repeats} repeats, at most {_eval_max_steps(out)} keyframes, the same scenes for "
        "every run; CLIP runs ground with CLIP at evaluation too.",
        "",
        "Rollout success, % (mean ± std over repeats; successes / episodes):",
        "",
        table,
        "",
        *([figures_md, ""] if figures_md else []),
    ]
    if {"abm_oracle", "abm_clip"} <= avg.keys():
        o, c = avg["abm_oracle"], avg["abm_clip"]
        lines.append(f"abm keeps {c['unseen']:.0f} % / {o['unseen']:.0f} % = "
                     f"{(c['unseen'] / o['unseen'] if o['unseen'] else float('nan')):.2f} of the oracle's unseen "
                     f"success with the learned grounder ({c['seen']:.0f} % / {o['seen']:.0f} % on seen objects).")
    swapped = next(iter(SWAPPED))
    if {"abm_clip", swapped} <= avg.keys():
        t, c = avg[swapped], avg["abm_clip"]
        lines.append(f"The oracle-trained policy grounded by CLIP only at evaluation reaches {t['seen']:.0f} % / "
                     f"{t['unseen']:.0f} % (seen / unseen), the CLIP-trained one {c['seen']:.0f} % / "
                     f"{c['unseen']:.0f} %.")
    if {"rvt_hash", "rvt_clip"} <= avg.keys():
        h, c = avg["rvt_hash"], avg["rvt_clip"]
        lines.append(f"CLIP text moves rvt from {h['unseen']:.0f} % to {c['unseen']:.0f} % on unseen objects "
                     f"({h['seen']:.0f} % to {c['seen']:.0f} % on seen).")
    missing = [name for name in [*RUNS, *SWAPPED] if name not in avg]
    if missing:
        lines.append(f"Not evaluated in this run (the script's METHODS): {', '.join(missing)}.")
    summary = "\n".join(lines) + "\n"
    if grounding and grounding_config:
        q = grounding_quality(grounding, tasks, grounding_config)
        if q:
            lines += ["", f"Quality of the grounding configuration `{grounding_config}` on these tasks' scenes "
                      "(`benchmarks/grounding_quality.py`, first observation of seeded scenes; "
                      "[grounding_quality.json](grounding_quality.json)):", "", q]
    if quality:
        normalization, threshold = _grounder_setting(config)
        q = mask_quality(quality, tasks, normalization, threshold)
        if q:
            lines += ["", f"Quality of the benchmark CLIP's mask field on these tasks' scenes at the grounder's "
                      f"setting ({normalization} at {threshold:g}; `benchmarks/clip_quality.py`, "
                      f"{quality.get('seeds', '?')} scenes per task and split):", "", q]
    return "\n".join(lines) + "\n", summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path, nargs="?", help="the folder given to scripts/clip_grounder.sh")
    parser.add_argument("--clip", type=Path, default=Path("models/benchmark-clip"), help="the CLIP model folder")
    parser.add_argument("--quality", type=Path, default=Path("runs/clip_quality.json"),
                        help="benchmarks/clip_quality.py JSON (skipped when missing)")
    parser.add_argument("--grounding-quality", type=Path, default=Path("docs/results/grounding_quality.json"),
                        help="benchmarks/grounding_quality.py JSON (skipped when missing)")
    parser.add_argument("--grounding-config", default="proposals (combined, no split)",
                        help="its configuration the abm_clip run grounded with (the package default)")
    parser.add_argument("--report", type=Path, default=Path("docs/results/clip_grounder.md"), help="markdown file")
    parser.add_argument("--readme", default="README.md", help="README to update ('' = do not touch it)")
    parser.add_argument("--command", default="bash scripts/clip_grounder.sh", help="the command to quote")
    add_figure_arguments(parser)
    args = parser.parse_args()

    store = args.report.with_suffix("")
    if redraw_only(args, parser, args.run_dir, figures, store):
        return
    quality = json.loads(args.quality.read_text()) if args.quality.is_file() else None
    knobs = ("CLIP", "DATA", "TASKS", "DEMOS", "STEPS", "EVAL_EPISODES", "REPEATS", "METHODS")
    args.command = " ".join([*(f"{k}={shlex.quote(os.environ[k])}" for k in knobs if k in os.environ),
                             args.command.strip()])
    store.mkdir(parents=True, exist_ok=True)
    for stale in [*store.glob("results_*.json"), *store.glob("training_*.csv")]:  # the kept JSON is this run's only
        stale.unlink()
    for folder in sorted(args.run_dir.glob("eval_*")):
        if (folder / "results.json").is_file():
            (store / f"results_{folder.name[len('eval_'):]}.json").write_text((folder / "results.json").read_text())
    for name in RUNS:
        if (args.run_dir / name / "log.csv").is_file():
            keep_training_log(args.run_dir / name, store / f"training_{name}.csv")
    grounding = json.loads(args.grounding_quality.read_text()) if args.grounding_quality.is_file() else None
    figs = figures(store, args.images)
    text, _ = report(args.run_dir, args.clip, args.command, quality, figure_markdown(figs, args.report.parent),
                     grounding, args.grounding_config)
    _, summary = report(args.run_dir, args.clip, args.command, quality,
                        figure_markdown(figs, Path(args.readme or ".").parent))
    args.report.write_text("# The learned (CLIP) grounder beside the oracle: abm, rvt and ifd\n\n" + text)
    print(text)
    if args.readme:
        readme = Path(args.readme)
        body = readme.read_text()
        if START in body and END in body:
            head, _, rest = body.partition(START)
            _, _, tail = rest.partition(END)
            summary = summary.replace("(clip_grounder/)", f"({args.report.with_suffix('')}/)")
            readme.write_text(f"{head}{START}\n{summary}\nFull report: [{args.report}]({args.report}).\n{END}{tail}")


if __name__ == "__main__":
    main()
