"""Evaluation: seeded rollouts of trained policies in ABM-Bench and the paper-style success tables."""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.evaluation.results import EpisodeOutcome, OutcomeLog, SuccessRate, aggregate, eval_seed, markdown_table

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = ["EpisodeOutcome", "OutcomeLog", "SuccessRate", "aggregate", "eval_seed", "markdown_table"]
