"""The quickstart's report folder (``abm quickstart``; ``OUT/report``): a README with the settings, the success
tables, the training curves, what the policy sees and the rollout GIFs, beside the pictures and an HTML page of the
rollouts."""

from __future__ import annotations

import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from abm.data.episode_store import EpisodeStore
from abm.evaluation.html_report import write_html_report
from abm.evaluation.plots import run_loss_curves, success_chart
from abm.evaluation.report import views_figure
from abm.evaluation.results import EpisodeOutcome, OutcomeLog, SuccessRate, aggregate, combined_table
from abm.policy import KeyframePolicy


@dataclass(frozen=True)
class QuickstartSettings:
    """What the quickstart ran, as its report's first paragraph states it.

    Attributes:
        tasks: the tasks (the first one's first demonstration shows what the policy sees).
        episodes: demonstrations per task (seen objects).
        policy_changes: the ``small`` preset's changes, as shown (e.g. ``{'resolution': 48, ...}``).
        steps: training steps per method.
        batch: training batch size.
        optimizer: the optimiser's name.
        lr: peak learning rate.
        grounder: the grounder, as described to the reader.
        eval_episodes: evaluation episodes per task and split.
        max_steps: keyframes per evaluation episode.
    """

    tasks: Sequence[str]
    episodes: int
    policy_changes: str
    steps: int
    batch: int
    optimizer: str
    lr: float
    grounder: str
    eval_episodes: int
    max_steps: int

    def sentence(self) -> str:
        """The report's first paragraph."""
        return (f"Tasks: {', '.join(self.tasks)}; {self.episodes} demonstrations per task (seen objects); "
                f"`small` preset with {self.policy_changes}, {self.steps} steps, batch {self.batch}, {self.optimizer} "
                f"lr {self.lr}; grounder: {self.grounder}; "
                f"{self.eval_episodes} evaluation episodes per task and split (max {self.max_steps} keyframes).")


def write_quickstart_report(report: Path, runs: Mapping[str, Path], eval_dirs: Sequence[Path], data: Path,
                            settings: QuickstartSettings, rates: list[SuccessRate] | None = None,
                            outcomes: list[EpisodeOutcome] | None = None) -> None:
    """Table, curves, example views and GIFs in one folder with a README that links them (``runs``: method -> run
    folder; ``eval_dirs``: the evaluation folders, one per run and split; ``data``: the demonstrations; ``rates``:
    the success rates, for the combined seen / unseen table; ``outcomes``: the episodes behind them, default every
    outcome logged in ``eval_dirs``). ``report/results.md`` (the per-split tables) must exist."""
    report.mkdir(parents=True, exist_ok=True)
    run_loss_curves(dict(runs), report / "training_curves.png")
    figures = []
    if "abm" in runs:
        store = EpisodeStore(data)
        index = store.select(tasks=[settings.tasks[0]])[0]
        episode = store.load(index)
        obs, _ = episode.steps[0]
        policy = KeyframePolicy.from_checkpoint(runs["abm"], device="cpu")
        seen = policy.explain(obs, episode.instruction, episode.object_names)  # what the network saw
        mask = None if seen.view_mask is None else seen.view_mask[:, None]
        views_figure(seen.view_images, mask, seen.view_names, report / "virtual_views.png")
        figures.append(f"![virtual views]({'virtual_views.png'})\n\n*{episode.instruction}*: the five virtual "
                       "views (top) and the target's centre-pixel mask in magenta (bottom).")
    gifs = sorted(g for folder in eval_dirs for g in folder.glob("gifs/*.gif"))
    overlays = [p for folder in eval_dirs for p in folder.glob("gifs/*_views.png")]
    for picture in [*gifs, *overlays]:  # rollouts and their heatmap overlays
        shutil.copy(picture, report / picture.name)
    if outcomes is None:
        outcomes = [o for folder in eval_dirs if (folder / "outcomes.jsonl").is_file()
                    for o in OutcomeLog(folder / "outcomes.jsonl").read()]
    if outcomes:
        success_chart(aggregate(outcomes), report / "success.png")
    write_html_report(outcomes, report / "report.html", report, "abm quickstart")
    lines = [
        "# abm quickstart report", "", settings.sentence(), "",
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
