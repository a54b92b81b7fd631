"""Evaluation: seeded rollouts of trained policies in ABM-Bench and the paper-style success tables."""

from abm.lazy import lazy_exports

# imported on first use (abm.lazy), so importing the package (every `abm` command does) stays light
__getattr__, __dir__ = lazy_exports(__name__, {
    "abm.evaluation.results": (
        "EpisodeOutcome", "OutcomeLog", "SuccessRate", "aggregate", "eval_seed", "markdown_table",
    ),
})

__all__ = ["EpisodeOutcome", "OutcomeLog", "SuccessRate", "aggregate", "eval_seed", "markdown_table"]
