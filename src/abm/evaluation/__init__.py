"""Evaluation: seeded rollouts of trained policies in ABM-Bench and the paper-style success tables."""

from abm.evaluation.results import EpisodeOutcome, OutcomeLog, SuccessRate, aggregate, eval_seed, markdown_table

__all__ = ["EpisodeOutcome", "OutcomeLog", "SuccessRate", "aggregate", "eval_seed", "markdown_table"]
