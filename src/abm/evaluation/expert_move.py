"""The "expert-move" evaluation (``abm eval --expert-keyframes move``): the policy's *move* keyframe replaced by
the scripted expert's move keyframe of the same scene, the reference of a perfect destination (issue 53).

The rule (:class:`ExpertMove`), read step by step before each predicted keyframe is executed:

* A *holding* is a run of consecutive executed steps after each of which the gripper holds the task's held
  object (:meth:`abm.sim.tasks.Task.held_object`); it starts with the step that grasped it.
* Step ``t`` is *the move* of a holding when the object is held before it (after step ``t - 1``), nothing was
  substituted in this holding yet, and either the object has been held for two steps already (after ``t - 2``
  and ``t - 1``: the grasp, then one step carried out with the object in hand, the lift), or the prediction's
  nearest expert keyframe (in position, :func:`abm.evaluation.step_records.nearest_expert`) is the move itself
  or a later keyframe (the policy already heads for the destination, skipping the lift).
* The move is executed as the expert's move keyframe instead of the prediction: the ``k``-th holding takes the
  expert's ``k``-th move keyframe (the last one once the expert has no more: a re-grasp after a drop is
  carried to the same destination). A holding gets at most one substitution; a policy that loops
  move / place afterwards acts on its own. Without expert keyframes (the expert could not run on the scene) or
  without a move among them nothing is substituted.

The expert's keyframes are those of :func:`abm.evaluation.step_records.expert_keyframes`, computed before the
rollout in a separate copy of the scene, so the rollout's scene is untouched; the step record of a substituted
step says so (``substituted: "move"``) and keeps the policy's own prediction (``policy_pos``, ``policy_quat``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from abm.evaluation.step_records import nearest_expert
from abm.types import KeyframeAction


@dataclass
class ExpertMove:
    """The expert-move rule of the module doc, for one rollout.

    Attributes:
        expert: the scripted expert's keyframes of the rollout's scene, in order.
        holding: executed steps after which the object has been held, in a row (0: not held now).
        substituted: whether the current holding had its move replaced.
        holdings: holdings started so far.
        steps: indices of the steps whose keyframe was replaced.
    """

    expert: Sequence[KeyframeAction]
    holding: int = 0
    substituted: bool = False
    holdings: int = 0
    steps: list[int] = field(default_factory=list)
    _step: int = 0

    @property
    def moves(self) -> list[int]:
        """Indices of the expert's move keyframes."""
        return [i for i, label in enumerate(self.expert) if label.kind == "move"]

    def choose(self, predicted: KeyframeAction, held: bool) -> KeyframeAction:
        """The keyframe to execute at this step: ``predicted``, or the expert's move keyframe when this step is
        the move (``held``: the object is held before the step, i.e. after the previous one)."""
        step, self._step = self._step, self._step + 1
        if not held:
            self.holding, self.substituted = 0, False
            return predicted
        if self.holding == 0:  # the previous step grasped it: a new holding
            self.holdings += 1
        self.holding += 1
        moves = self.moves
        if self.substituted or not moves:
            return predicted
        move = moves[min(self.holdings, len(moves)) - 1]
        index, _, _ = nearest_expert(predicted, self.expert)
        if self.holding < 2 and index < move:
            return predicted
        self.substituted = True
        self.steps.append(step)
        return self.expert[move]
