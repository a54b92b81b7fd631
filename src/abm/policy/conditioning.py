"""What a variant is conditioned on: the language goal text and the per-point mask field.

This module is the policy's only contact with :mod:`abm.grounding` (``decompose_instruction``,
``make_grounder``); grounding results are normalised to :class:`PointMask`.

Grounders are described by a JSON-compatible spec stored in checkpoints: ``{"kind": "oracle"}`` or
``{"kind": "clip", ...options passed to make_grounder}``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from abm.geometry import PointCloud
from abm.policy.variants import VariantSpec
from abm.types import Observation

PLACEHOLDER = "X"


@dataclass
class PointMask:
    """A mask field over the points of a cloud.

    Attributes:
        mask: ``(N,)`` float32 in {0, 1}.
        heatmap: ``(N,)`` float32 in [0, 1] (soft score; equals ``mask`` for the oracle).
        found: whether any point was selected.
    """

    mask: np.ndarray
    heatmap: np.ndarray
    found: bool


def _replace_target(instruction: str, target: str) -> str | None:
    pattern = re.compile(r"\b" + re.escape(target) + r"\b", re.IGNORECASE)
    if not pattern.search(instruction):
        return None
    return pattern.sub(PLACEHOLDER, instruction, count=1)


def split_instruction(instruction: str, object_names: Mapping[int, str] | None = None,
                      target: str | None = None) -> tuple[str, str]:
    """Split an instruction into ``(target X, skill text with X replaced by "X")``.

    Uses ``abm.grounding.instruction.decompose_instruction`` (the templates); when no template
    matches, replaces a known ``target`` name, or the longest scene object name found in the text, by
    ``X``. Training and inference call this the same
    way, so the skill text the policy sees is the same in both.

    Raises:
        ValueError: no target can be identified, or the instruction asks for several skills
            (:class:`abm.grounding.instruction.MultiStepInstructionError`).
    """
    from abm.grounding.instruction import MultiStepInstructionError, decompose_instruction

    try:
        obj, skill = decompose_instruction(instruction)
        return str(obj), str(skill)
    except MultiStepInstructionError:
        raise  # several skills in one instruction: never run just one of them silently
    except ValueError:  # no template matches: fall back to a scene object name
        pass
    names = ([target] if target else []) + sorted(set((object_names or {}).values()), key=len, reverse=True)
    for name in names:
        skill = _replace_target(instruction, name)
        if skill is not None:
            return name, skill
    raise ValueError(f"cannot find the target object in instruction {instruction!r}")


def language_text(spec: VariantSpec, instruction: str, skill: str | None) -> str:
    """The text a variant reads: the skill text or the whole instruction."""
    if spec.language == "skill":
        if skill is None:
            raise ValueError(f"variant {spec.name!r} needs the skill text of {instruction!r}")
        return skill
    return instruction


def make_grounder_from_spec(spec: Mapping[str, Any]) -> Any:
    """Build a grounder (``abm.grounding.make_grounder``) from its JSON-compatible spec."""
    from abm.grounding import make_grounder

    options = {k: v for k, v in spec.items() if k != "kind"}
    return make_grounder(spec.get("kind", "oracle"), **options)


def ground_points(grounder: Any, observation: Observation, cloud: PointCloud, target: str,
                  object_names: Mapping[int, str]) -> PointMask:
    """Run a grounder and normalise its result to :class:`PointMask` (float32 arrays of length N)."""
    field = grounder.ground(observation, cloud, target, dict(object_names))
    mask = np.asarray(field.mask, np.float32).reshape(-1)
    heat = getattr(field, "heatmap", None)
    heat = mask.copy() if heat is None else np.asarray(heat, np.float32).reshape(-1)
    if mask.shape[0] != len(cloud) or heat.shape[0] != len(cloud):
        raise ValueError(f"grounder returned {mask.shape[0]} mask values for a cloud of {len(cloud)} points")
    found = bool(getattr(field, "found", mask.any()))
    return PointMask(mask, np.clip(heat, 0.0, 1.0), found)
