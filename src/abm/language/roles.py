"""An instruction's roles: the objects of its sub-goals, its skill text and where it brings its object.

* :func:`split_roles` / :func:`split_instruction`: ``"put the ketchup in the bowl"`` -> ``(("ketchup", "bowl"),
  "put X in Y")`` by the templates (:mod:`abm.language.instruction`), else by a scene object name found in the text;
  training data (:mod:`abm.data.keyframes`), the policy's conditioning (:mod:`abm.grounding.conditioning`),
  evaluation, the viewer and ``abm run`` split every instruction through it, so all see the same skill text;
* :func:`destination_for` / :func:`instruction_destination`: the object a skill's tasks bring X to (``Task.destination``
  of :data:`abm.sim.tasks.TASKS`: the plate, the target pad; Y of a two-target instruction), which
  :mod:`abm.grounding.conditioning` grounds into the policy's second mask.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

from abm.errors import ConfigError
from abm.language.instruction import PLACEHOLDER, MultiStepInstructionError, default_parser
from abm.sim.tasks import TASKS


def _replace_target(instruction: str, target: str) -> str | None:
    pattern = re.compile(r"\b" + re.escape(target) + r"\b", re.IGNORECASE)
    if not pattern.search(instruction):
        return None
    return pattern.sub(PLACEHOLDER, instruction, count=1)


def split_roles(instruction: str, object_names: Mapping[int, str] | None = None,
                target: str | None = None) -> tuple[tuple[str, ...], str]:
    """Split an instruction into its sub-goals' objects and the skill text: ``((X,), "put X in the plate")``
    or, for a two-target skill, ``((X, Y), "put X in Y")``.

    Uses the templates (:mod:`abm.language.instruction`); when no template matches, replaces a known
    ``target`` name, or the longest scene object name found in the text, by ``X`` (one sub-goal).
    Training and inference call this the same way, so the skill text the policy sees is the same in both.

    Raises:
        ValueError: no target can be identified, or the instruction asks for several skills
            (:class:`~abm.language.instruction.MultiStepInstructionError`).
    """
    try:  # the scene's names never read as a negation, condition or choice (an object called "either box")
        parsed = default_parser().parse(instruction, names=tuple((object_names or {}).values()))
        return parsed.targets, parsed.skill
    except MultiStepInstructionError:
        raise  # several skills in one instruction: never run just one of them silently
    except ValueError:  # no template matches: fall back to a scene object name
        pass
    names = ([target] if target else []) + sorted(set((object_names or {}).values()), key=len, reverse=True)
    for name in names:
        skill = _replace_target(instruction, name)
        if skill is not None:
            return (name,), skill
    raise ConfigError(f"cannot find the target object in instruction {instruction!r}")


def split_instruction(instruction: str, object_names: Mapping[int, str] | None = None,
                      target: str | None = None) -> tuple[str, str]:
    """``(X, skill text)``: :func:`split_roles` for the first sub-goal's object."""
    targets, skill = split_roles(instruction, object_names, target)
    return targets[0], skill


def destination_for(tasks: Sequence[str], targets: Sequence[str]) -> str | None:
    """The destination object of an instruction whose skill the benchmark ``tasks`` use and whose sub-goals name
    ``targets`` (``(X,)`` or ``(X, Y)``): what the tasks declare (``Task.destination``, X / Y filled in), ``None``
    when they declare none or disagree. A two-target skill no benchmark task uses (a user's) brings X to Y."""
    known = [TASKS[t] for t in tasks if t in TASKS]
    if not known:
        return targets[1] if len(targets) > 1 else None
    names = {task.destination_name(tuple(targets)) for task in known}
    return names.pop() if len(names) == 1 else None


def instruction_destination(instruction: str, targets: Sequence[str] | None = None) -> str | None:
    """The destination object of ``instruction`` (:func:`destination_for` of its parse by the templates), with
    ``targets`` in place of the parsed X (and Y) when given (the oracle's ground-truth names); ``None`` when no
    template matches."""
    try:
        parsed = default_parser().parse(instruction)
    except ValueError:  # no template (the scene-name fallback of split_roles): no known task, no destination
        return None
    return destination_for(parsed.tasks, tuple(targets) if targets else parsed.targets)
