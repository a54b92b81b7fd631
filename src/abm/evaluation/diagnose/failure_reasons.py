"""The ``failure_reasons`` diagnosis: why rollouts stop, a policy's closed-loop keyframes traced against the expert's
per keyframe kind (the measurement is :mod:`abm.evaluation.motion_trace`).

``abm eval`` names one failure reason per episode from its step records (:func:`abm.evaluation.step_records.
episode_failure`: the first stop the policy did not recover from, else ``grasp missed`` or ``timeout``), which the
report counts per model and split. This diagnosis says more of a stop: it rolls each model out on the evaluation
scenes of ``abm eval`` (repeat 0, the same RNG state) and records per step the motion's status (reached / blocked /
unreachable / collided), how far the arm stopped from the predicted pose, and the prediction's distance and height
offset from the expert's keyframe of the same index: at which keyframe kind motions are blocked, and whether the
blocked targets are far from the expert's (a wrong place) or just below it (pressing into something).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.evaluation.diagnose.request import DiagnosisRequest, write_json
from abm.evaluation.motion_trace import StepTrace, as_records, markdown, summarise_traces, trace_rollout
from abm.evaluation.policies import rollout_state
from abm.evaluation.results import eval_seed
from abm.evaluation.runner import method_labels
from abm.machine import describe_machine
from abm.policy import KeyframePolicy

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FailureReasons(DiagnosisRequest):
    """Trace every model's rollouts on ``episodes`` evaluation scenes per task.

    Attributes:
        models: run folders, checkpoints or zoo files (each labelled as in ``abm eval``'s tables).
        tasks: the tasks rolled out.
        out: the JSON written (``None``: nothing written): ``machine``, ``split``, ``episodes`` and ``methods``
            (label -> task -> ``successes``, ``summary`` (rows of :func:`abm.evaluation.motion_trace.
            summarise_traces`) and ``steps`` (every step's trace)).
        split: the object split of the scenes.
        episodes: scenes per task (the seeds of ``abm eval``, repeat 0).
    """

    kind = "failure_reasons"

    models: tuple[Path, ...]
    tasks: tuple[str, ...]
    out: Path | None = None
    split: str = "seen"
    episodes: int = 10

    def traces(self, model: Path, task: str) -> list[StepTrace]:
        """Every step of ``model``'s rollouts on ``task`` (a fresh policy per scene, as ``abm eval`` loads it)."""
        traces = []
        for episode in range(self.episodes):
            seed = eval_seed(0, episode)
            with rollout_state(seed):  # the RNG state abm eval gives this scene
                policy = KeyframePolicy.from_checkpoint(model)
                policy.reset()
                traces += trace_rollout(policy.act, task, self.split, seed)
        return traces

    def run(self) -> dict[str, Any]:
        """Roll out and trace every model on every task, write :attr:`out` and return its content (each summary
        table is logged)."""
        labels = method_labels(self.models)
        start = time.perf_counter()
        methods: dict[str, dict[str, Any]] = {}
        for model in self.models:
            name = labels[str(model)]
            for task in self.tasks:
                traces = self.traces(model, task)
                rows = summarise_traces(traces)
                wins = sum(t.success for t in traces)
                log.info("\n%s · %s · %s: %d/%d successes\n%s", name, task, self.split, wins, self.episodes,
                         markdown(rows))
                methods.setdefault(name, {})[task] = {"successes": wins, "summary": rows, "steps": as_records(traces)}
        log.info("\nmachine: %s; %.0f s", describe_machine(), time.perf_counter() - start)
        payload = {"machine": describe_machine(), "split": self.split, "episodes": self.episodes, "methods": methods}
        write_json(self.out, payload)
        return payload
