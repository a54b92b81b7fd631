"""The ``abm quickstart`` command (its parser and :class:`QuickstartConfig`: :mod:`abm.cli.quickstart`)."""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

from abm.cli.quickstart import SPEC, QuickstartConfig, recipe
from abm.cli.train import POLICY_DEST
from abm.configuration import config_from_args, overrides_from_args
from abm.errors import ExternalError
from abm.evaluation.results import OutcomeLog, aggregate, combined_table
from abm.evaluation.runner import crash_summary, write_tables
from abm.experiments.report.pages.quickstart import QuickstartSettings, write_quickstart_report
from abm.experiments.spec import EvalSplit, ExperimentSpec, Resources, RunSpec, load_spec
from abm.experiments.stages import Engine
from abm.grounding.config import as_grounder_config
from abm.grounding.default import (  # noqa: F401  (benchmark_clip_dir: also quickstart's name for it)
    BENCHMARK_CLIP_ENV,
    benchmark_clip_dir,
    default_grounder,
    hub_reachable,
)
from abm.train.config import preset_policy


def choose_grounder(cfg: QuickstartConfig) -> tuple[str, dict[str, str], str]:
    """The best grounder this machine has: ``(kind, options, description for the report)``, in the order every
    command uses (:func:`abm.grounding.default.default_grounder`): ``--clip-model`` if given (an error if it does
    not load); the pretrained CLIP (from the local Hugging Face cache, or fetched from the hub when it answers
    within 3 s, unless ``--offline``); the benchmark CLIP (:func:`benchmark_clip_dir`); else the oracle grounder,
    with a loud warning.
    """
    online = not cfg.offline and hub_reachable()
    choice = default_grounder(cfg.clip_model, cfg.device, download=online)
    print(choice.startup_line("quickstart"))
    return choice.kind, choice.options, choice.description


def quickstart_spec(cfg: QuickstartConfig, grounder: str) -> ExperimentSpec:
    """The quickstart spec (``configs/experiments/quickstart.yaml``) with the command's flags applied: the tasks,
    demonstrations, methods, recipe values, evaluation sizes and the grounder :func:`choose_grounder` picked.

    The methods train side by side, one process each with its share of the cores, when the device is the CPU
    and the machine has a core per method (on a CPU this beats training them in turn)."""
    base = load_spec(SPEC)
    tasks = tuple(cfg.tasks)
    base_config = next(iter(base.runs.values())).config  # the quickstart recipe, with the command's values
    train = replace(base_config, batch=cfg.batch, lr=cfg.lr, optimizer=cfg.optimizer,
                    warmup=min(cfg.warmup, cfg.steps // 4), checkpoint_every=max(50, cfg.steps // 4),
                    device=cfg.device, seed=cfg.seed, tasks=list(tasks), steps=cfg.steps,
                    grounder=as_grounder_config(grounder))
    runs = {m: RunSpec(name=m, label=m, grounding=grounder, config=replace(
        train, method=m, policy=preset_policy(train.preset, m, cfg.policy.preset_changes()))) for m in cfg.methods}
    cores = os.cpu_count() or 1
    parallel = cfg.device == "cpu" and len(runs) > 1 and cores >= len(runs)
    resources = Resources(trainings_at_a_time=len(runs) if parallel else 1,
                          threads_each=max(1, cores // len(runs)) if parallel else cores)
    return replace(
        base, out=str(cfg.out), kept=str(cfg.out / "kept"),
        data=replace(base.data, tasks=tasks, episodes=cfg.episodes, workers=cfg.workers, seed=cfg.seed,
                     resolution=cfg.resolution),
        training=replace(base.training, tasks=tasks, steps=cfg.steps), runs=runs, resources=resources,
        evaluation=replace(base.evaluation, episodes=cfg.eval_episodes, repeats=1, workers=cfg.workers,
                           max_steps=cfg.max_steps, gifs=1, device=cfg.device,
                           splits=tuple(EvalSplit(split, tasks) for split in ("seen", "unseen"))))


def run_quickstart(cfg: QuickstartConfig) -> Path:
    """Run the quickstart spec's stages (:mod:`abm.experiments`: data, grounding, training, evaluation; every
    stage resumes), then write the report folder
    (:func:`abm.experiments.report.pages.quickstart.write_quickstart_report`); returns it."""
    start = time.perf_counter()
    grounder, options, grounder_text = choose_grounder(cfg)
    spec = quickstart_spec(cfg, grounder)
    engine = Engine(spec, root=Path("."), out=cfg.out, clip_model=options.get("model"))
    layout = engine.layout
    report = cfg.out / "report"
    side = " side by side, one process each" if spec.resources.trainings_at_a_time > 1 else ""
    steps = [(["data"], f"demonstrations: {cfg.episodes} per task, seen objects -> {layout.data}"),
             (["ground", "train"], f"training {', '.join(cfg.methods)} (small preset, {cfg.steps} steps, "
              f"{cfg.policy.preset_changes()}){side} -> {cfg.out}"),
             (["eval"], f"evaluating {', '.join(cfg.methods)} on seen and unseen objects ({cfg.eval_episodes} "
              "episodes per task)")]
    for i, (stages, what) in enumerate(steps, 1):
        print(f"[{i}/4] {what}")
        if engine.run(stages) != 0:
            raise ExternalError(f"the quickstart's {' and '.join(stages)} stage failed: see the logs in "
                             f"{layout.out / 'logs'}")

    print(f"[4/4] report -> {report}")
    runs = {m: layout.run_dir(m) for m in cfg.methods}
    folders = [layout.eval_dir(m, split) for m in cfg.methods for split in ("seen", "unseen")]
    outcomes = [o for folder in folders if (folder / "outcomes.jsonl").is_file()
                for o in OutcomeLog(folder / "outcomes.jsonl").read()]
    rates = aggregate(outcomes)
    table = combined_table(rates)
    write_tables(rates, report)
    write_quickstart_report(report, runs, folders, layout.data, report_settings(cfg, grounder_text), rates,
                            outcomes)
    print(table)
    print(f"done in {(time.perf_counter() - start) / 60:.1f} min; report: {report}/README.md")
    crashes = crash_summary(outcomes)
    if crashes:  # the report is written, but a crash is not a measurement: the command fails
        raise ExternalError(f"{crashes}; report: {report}/README.md")
    return report


def report_settings(cfg: QuickstartConfig, grounder: str) -> QuickstartSettings:
    """What the report's first paragraph states of the run (``grounder``: the grounder as described to the
    reader)."""
    return QuickstartSettings(tasks=cfg.tasks, episodes=cfg.episodes, policy_changes=str(cfg.policy.preset_changes()),
                              steps=cfg.steps, batch=cfg.batch, optimizer=cfg.optimizer, lr=cfg.lr, grounder=grounder,
                              eval_episodes=cfg.eval_episodes, max_steps=cfg.max_steps)


def run(args: argparse.Namespace) -> int:
    changes = {**recipe()["policy"], **overrides_from_args(args, POLICY_DEST), **dict(args.overrides)}
    # bad policy settings fail here, before any work
    run_quickstart(config_from_args(QuickstartConfig, args, policy=preset_policy("small", "abm", changes)))
    return 0
