"""The ``abm quickstart`` command (its parser and :class:`QuickstartConfig`: :mod:`abm.cli.quickstart`)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from abm.cli import configure_logging
from abm.cli.quickstart import QuickstartConfig, recipe
from abm.cli.train import POLICY_DEST
from abm.configuration import CPU_CLIP_MODEL, GPU_CLIP_MODEL, config_from_args, overrides_from_args
from abm.data.episode_store import EpisodeStore
from abm.data.generate import generate
from abm.evaluation.html_report import write_html_report
from abm.evaluation.plots import success_chart
from abm.evaluation.report import plot_training_curves, views_figure
from abm.evaluation.results import EpisodeOutcome, OutcomeLog, aggregate, combined_table
from abm.evaluation.runner import EvalSettings, crash_summary, evaluate, write_tables
from abm.grounding.clip import ClipWeightsNotFoundError, load_clip
from abm.policy import KeyframePolicy
from abm.policy.config import PolicyConfig
from abm.train.config import TrainConfig
from abm.train.loop import train
from abm.workers import die_with_parent

BENCHMARK_CLIP_ENV = "ABM_BENCHMARK_CLIP"
DEFAULT_BENCHMARK_CLIP = "~/.cache/abm/benchmark-clip"


ZOO_BENCHMARK_CLIP = Path("models/benchmark-clip")  # committed with the model zoo (abm zoo list)


def benchmark_clip_dir() -> Path:
    """Where the quickstart looks for the benchmark CLIP (``abm clip train --out DIR``): ``$ABM_BENCHMARK_CLIP``,
    else the model zoo's copy in a repository checkout (``models/benchmark-clip``, relative to the working
    folder), else ``~/.cache/abm/benchmark-clip``."""
    if os.environ.get(BENCHMARK_CLIP_ENV):
        return Path(os.environ[BENCHMARK_CLIP_ENV]).expanduser()
    if (ZOO_BENCHMARK_CLIP / "config.json").is_file():
        return ZOO_BENCHMARK_CLIP
    return Path(DEFAULT_BENCHMARK_CLIP).expanduser()


def hub_reachable(host: str = "huggingface.co", timeout_s: float = 3.0) -> bool:
    """Whether the model hub answers a TCP connection within ``timeout_s`` (so a download is worth trying)."""
    import socket

    try:
        with socket.create_connection((host, 443), timeout=timeout_s):
            return True
    except OSError:
        return False


def choose_grounder(cfg: QuickstartConfig) -> tuple[str, dict, str]:
    """The best grounder this machine has: ``(kind, options, description for the report)``.

    In order: ``--clip-model`` if given (an error if it does not load); the pretrained CLIP (from the local
    Hugging Face cache, or fetched from the hub when it answers within 3 s, unless ``--offline``); the
    benchmark CLIP trained on ABM-Bench renders (:func:`benchmark_clip_dir`); else the oracle grounder,
    with a loud warning.
    """
    online = not cfg.offline and hub_reachable()
    tried = []
    pretrained = GPU_CLIP_MODEL if cfg.device.startswith("cuda") else CPU_CLIP_MODEL
    bench = benchmark_clip_dir()
    candidates = [(cfg.clip_model, f"CLIP {cfg.clip_model}")] if cfg.clip_model else [
        (pretrained, f"pretrained CLIP {pretrained}"),
        (str(bench), f"benchmark CLIP trained on ABM-Bench renders ({bench}; abm clip train)"),
    ]
    for model, description in candidates:
        try:
            load_clip(model, device="cpu", allow_download=online and model == pretrained)
        except (ClipWeightsNotFoundError, OSError) as err:
            if cfg.clip_model:  # asked for by name: say so rather than silently run another grounder
                raise ValueError(f"--clip-model {cfg.clip_model}: {str(err).splitlines()[0]}") from err
            tried.append(f"{model}: {str(err).splitlines()[0]}")
            continue
        print(f"grounder: {description}")
        return "clip", {"model": model}, description
    print("WARNING: no CLIP weights found (" + "; ".join(tried) + ")\n"
          "WARNING: using the ORACLE grounder (simulator segmentation) instead of CLIP; the masks are "
          "ground truth, so the table measures the policy, not CLIP grounding. Provide weights with "
          f"--clip-model DIR, or train the benchmark CLIP once: abm clip train --out {bench} "
          "(see docs/grounding.md).", file=sys.stderr)
    return "oracle", {}, "oracle (simulator segmentation; no CLIP weights found)"


def run_quickstart(cfg: QuickstartConfig) -> Path:
    """Run all stages; returns the report folder."""
    import torch


    PolicyConfig.from_preset("small", "abm", **cfg.policy_overrides)  # bad policy settings fail before any work
    start = time.perf_counter()
    out = cfg.out
    data, runs_dir, report = out / "data", out / "runs", out / "report"
    torch.set_num_threads(max(1, torch.get_num_threads()))
    grounder, options, grounder_text = choose_grounder(cfg)

    print(f"[1/4] demonstrations: {cfg.episodes} per task, seen objects -> {data}")
    for i, task in enumerate(cfg.tasks):
        generate(task, "seen", cfg.episodes, data, workers=cfg.workers, seed=cfg.seed + 1000 * i,
                 resolution=cfg.resolution)

    runs = {}
    configs = []
    for i, method in enumerate(cfg.methods):
        run = runs_dir / method
        configs.append(TrainConfig(
            method=method, preset="small", out=run, data=data, tasks=list(cfg.tasks), splits=["seen"],
            steps=cfg.steps, batch=cfg.batch, lr=cfg.lr, optimizer=cfg.optimizer,
            warmup=min(cfg.warmup, cfg.steps // 4), checkpoint_every=max(50, cfg.steps // 4), device=cfg.device,
            grounder=grounder, grounder_options=options, seed=cfg.seed, resume=True,
            policy_overrides=dict(cfg.policy_overrides), progress=i == 0))
        runs[method] = run
    parallel = cfg.device == "cpu" and len(configs) > 1 and (os.cpu_count() or 1) >= len(configs)
    print(f"[2/4] training {', '.join(cfg.methods)} (small preset, {cfg.steps} steps, {cfg.policy_overrides})"
          + (" side by side, one process each" if parallel else "") + f" -> {runs_dir}")
    if parallel:
        # one process per method with its share of the cores: on a CPU this beats training them in turn
        threads = max(1, (os.cpu_count() or 1) // len(configs))
        with ProcessPoolExecutor(len(configs), mp_context=get_context("spawn"), initializer=die_with_parent) as pool:
            for summary in pool.map(_train_with_threads, configs, [threads] * len(configs)):
                print(f"  {summary['method']}: {summary['steps']} steps, {summary['seconds'] / 60:.1f} min")
    else:
        for tc in configs:
            train(tc)

    settings = EvalSettings(device=cfg.device, resolution=cfg.resolution, max_steps=cfg.max_steps)
    eval_dir = out / "eval"
    rates = []
    outcomes: list[EpisodeOutcome] = []
    for split in ("seen", "unseen"):
        print(f"[3/4] evaluating {', '.join(cfg.methods)} on {split} objects ({cfg.eval_episodes} episodes per task)")
        rates += evaluate(list(runs.values()), cfg.tasks, split, eval_dir / split, episodes=cfg.eval_episodes,
                          repeats=1, workers=cfg.workers, settings=settings, gifs=1, collect=outcomes)

    print(f"[4/4] report -> {report}")
    table = combined_table(rates)
    write_tables(rates, report)
    write_report(report, runs, eval_dir, data, cfg, grounder_text, rates, outcomes)
    print(table)
    print(f"done in {(time.perf_counter() - start) / 60:.1f} min; report: {report}/README.md")
    crashes = crash_summary(outcomes)
    if crashes:  # the report is written, but a crash is not a measurement: the command fails
        raise ValueError(f"{crashes}; report: {report}/README.md")
    return report


def _train_with_threads(config, threads: int) -> dict:
    """Train one run in a worker process with ``threads`` torch threads (see :func:`run_quickstart`)."""
    import torch


    configure_logging()
    torch.set_num_threads(threads)
    return train(config)


def write_report(report: Path, runs: dict[str, Path], eval_dir: Path, data: Path, cfg: QuickstartConfig,
                 grounder: str, rates: list | None = None, outcomes: list[EpisodeOutcome] | None = None) -> None:
    """Table, curves, example views and GIFs in one folder with a README that links them (``rates``: the
    success rates, for the combined seen / unseen table; ``outcomes``: the episodes behind them, default every
    outcome logged under ``eval_dir``)."""
    report.mkdir(parents=True, exist_ok=True)
    plot_training_curves({m: r for m, r in runs.items()}, report / "training_curves.png")
    figures = []
    if "abm" in runs:
        store = EpisodeStore(data)
        index = store.select(tasks=[cfg.tasks[0]])[0]
        episode = store.load(index)
        obs, _ = episode.steps[0]
        policy = KeyframePolicy.from_checkpoint(runs["abm"], device="cpu")
        seen = policy.explain(obs, episode.instruction, episode.object_names)  # what the network saw
        mask = None if seen.view_mask is None else seen.view_mask[:, None]
        views_figure(seen.view_images, mask, seen.view_names, report / "virtual_views.png")
        figures.append(f"![virtual views]({'virtual_views.png'})\n\n*{episode.instruction}*: the five virtual "
                       "views (top) and the target's centre-pixel mask in magenta (bottom).")
    gifs = sorted(eval_dir.glob("*/gifs/*.gif"))
    for picture in [*gifs, *eval_dir.glob("*/gifs/*_views.png")]:  # rollouts and their heatmap overlays
        shutil.copy(picture, report / picture.name)
    if outcomes is None:
        outcomes = [o for log in sorted(eval_dir.glob("*/outcomes.jsonl")) for o in OutcomeLog(log).read()]
    if outcomes:
        success_chart(aggregate(outcomes), report / "success.png")
    write_html_report(outcomes, report / "report.html", report, "abm quickstart")
    lines = [
        "# abm quickstart report", "",
        f"Tasks: {', '.join(cfg.tasks)}; {cfg.episodes} demonstrations per task (seen objects); "
        f"`small` preset with {cfg.policy_overrides}, {cfg.steps} steps, batch {cfg.batch}, {cfg.optimizer} "
        f"lr {cfg.lr}; grounder: {grounder}; "
        f"{cfg.eval_episodes} evaluation episodes per task and split (max {cfg.max_steps} keyframes).", "",
        "## Success rate (%)", "", *([combined_table(rates), "", "Per split:", ""] if rates else []),
        (report / "results.md").read_text(), "",
        *(["![success rate per task and split; error bars: std over repeats](success.png)", ""]
          if (report / "success.png").is_file() else []),
        "## Training curves", "", "![training curves](training_curves.png)", "",
        "## What the policy sees", "", *figures, "",
        "## Rollouts", "", "Failure reasons and the GIFs side by side: [report.html](report.html)", "",
        *[f"![{g.stem}]({g.name})" for g in gifs], "",
    ]
    (report / "README.md").write_text("\n".join(lines))


def run(args: argparse.Namespace) -> int:
    overrides = {**recipe()["policy"], **overrides_from_args(args, POLICY_DEST), **dict(args.overrides)}
    run_quickstart(config_from_args(QuickstartConfig, args, policy_overrides=overrides))
    return 0
