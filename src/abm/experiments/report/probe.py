"""A probe's records as its report sections read them: one JSON object (``report`` section key ``source``,
relative to the root, e.g. docs/results/zoom_probe.json) with lists of rows, each naming its ``arm`` (a run's
label) and the training ``step`` of the checkpoint it measured:

* ``fit``: ``{arm, step, augment, task, keyframe, yaw_ce, ...}``: the teacher-forced yaw cross-entropy (nats) on
  the training keyframes (:mod:`abm.evaluation.diagnose`'s rotation fit; ``task`` ``all`` and ``keyframe``
  ``all`` for the means over them);
* ``accuracy``: ``{arm, step, task, split, keyframe, yaw_error_deg, position_error_cm}``: the keyframe accuracy's
  medians on evaluation scenes;
* ``rollouts``: ``{arm, step, task, split, successes, episodes}``.

The sections (``probe_fit``, ``probe_accuracy``, ``probe_rollouts``) show the section's runs as columns, by
their labels, each at its final step (the runs' training steps)."""

from __future__ import annotations

import json
from typing import Any

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def probe_records(ctx: Context, section: Section, key: str) -> list[dict[str, Any]]:
    """The ``key`` rows (``fit``, ``accuracy``, ``rollouts``) of the section's source (``[]`` when it is
    missing)."""
    path = ctx.layout.root / section.source
    return json.loads(path.read_text()).get(key, []) if path.is_file() else []


def arms(ctx: Context, section: Section) -> list[str]:
    """The section's runs (default: every run of the spec) as the records name them: by their labels."""
    return [ctx.label(run) for run in section.runs or ctx.spec.runs]


def final_step(ctx: Context) -> int:
    """The step of the runs' final checkpoints (their training steps)."""
    return next(iter(ctx.spec.runs.values())).config.steps
