"""The ``skill_text`` diagnosis: does a mask policy's keyframe follow its skill text?

A mask variant (abm, stack, concat-*) reads the target's mask and the instruction's skill text, the instruction
with the target replaced by X ("put X in the wine rack"). On a task's evaluation scenes (the seeds of ``abm
eval``), teacher-forced on the expert's rollout like the ``keyframe_accuracy`` diagnosis, the policy predicts one
keyframe kind once with the scene's own instruction and once with every other skill text of the given tasks,
worded about the same target ("take the wine bottle off the frypan"). Per skill text: the median position error
(cm) against the expert's label and the median distance (cm) from the prediction with the scene's own text
(:func:`abm.evaluation.keyframe_accuracy.skill_text_probe`). A policy that reads its text moves its prediction when
the text changes; one that stays put has not learned to tell those skills apart by their text.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.errors import ConfigError
from abm.evaluation.diagnose.request import DiagnosisRequest, write_json
from abm.evaluation.keyframe_accuracy import skill_text_probe, task_skills
from abm.grounding.config import grounder_from_flags
from abm.machine import describe_machine
from abm.policy import KeyframePolicy

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SkillTextProbe(DiagnosisRequest):
    """Probe one mask policy on one task.

    Attributes:
        model: a mask variant's run folder, checkpoint or zoo file.
        task: the task whose evaluation scenes are probed.
        skill_tasks: the tasks whose skill texts are tried (the first evaluation scene of each names its text).
        out: the JSON written (``None``: nothing written): ``machine``, ``run`` (``model``), ``task``, ``split``,
            ``kind``, ``grounder`` and ``rows`` (per skill text: ``skill``, ``own``, ``n``, ``position_cm_median``,
            ``moved_cm_median``, ``task``).
        keyframe: the expert keyframe kind probed (the JSON's ``kind``).
        split: the object split of the scenes.
        episodes: scenes (the seeds of ``abm eval``, repeat 0).
        resolution: camera pixels (as in training).
        grounder: a grounder kind that replaces the checkpoint's (``oracle``: the simulator's mask).
    """

    kind = "skill_text"

    model: Path
    task: str
    skill_tasks: tuple[str, ...]
    out: Path | None = None
    keyframe: str = "move"
    split: str = "seen"
    episodes: int = 5
    resolution: int = 128
    grounder: str | None = None

    def run(self) -> dict[str, Any]:
        """Probe, write :attr:`out` and return its content (the table is logged).

        Raises:
            ConfigError: the model is not a mask variant (it reads the whole instruction, not a skill text).
        """
        policy = KeyframePolicy.from_checkpoint(self.model, grounder=grounder_from_flags(self.grounder))
        if policy.spec.language != "skill":
            raise ConfigError(f"{self.model} is a {policy.spec.name!r} policy: it reads the whole instruction, not a "
                              "skill text; the probe needs a mask variant (abm, stack, concat-*)")
        skills = task_skills(self.skill_tasks)
        start = time.perf_counter()
        rows = skill_text_probe(policy.act, self.task, self.split, self.episodes, self.keyframe, list(skills),
                                self.resolution)
        for r in rows:
            r["task"] = skills[str(r["skill"])]
        log.info("machine: %s; %s, %s %s, keyframe %r, grounder %s, %s keyframes; %.0f s\n%s", describe_machine(),
                 self.model, self.task, self.split, self.keyframe, self.grounder or "of the checkpoint", rows[0]["n"],
                 time.perf_counter() - start, table(rows))
        payload = {"machine": describe_machine(), "run": str(self.model), "task": self.task, "split": self.split,
                   "kind": self.keyframe, "grounder": self.grounder, "rows": rows}
        write_json(self.out, payload)
        return payload


def table(rows: list[dict[str, Any]]) -> str:
    """The probe's rows as a markdown table (the scene's own skill text in bold)."""
    lines = ["| skill text | its task | position error cm (median) | moved from own text cm (median) |",
             "|---|---|---|---|"]
    for r in rows:
        name = f"**{r['skill']}** (own)" if r["own"] else r["skill"]
        lines.append(f"| {name} | {r['task']} | {r['position_cm_median']:.1f} | {r['moved_cm_median']:.1f} |")
    return "\n".join(lines)
