"""Whether to act on a grounded target: one decision shared by ``abm run``, ``abm ground --strict`` and the
evaluation logs.

A grounder always returns a mask, also when it did not find the target (CLIP's fallback marks its best
guess, which may be the gripper). :func:`decide_target` judges that answer together with the instruction's
target name and the scene's vocabulary (segmentation id -> object name; empty for a real camera) and
refuses, with a reason naming what the scene holds and the candidates, when

1. the instruction names no object (an empty target);
2. the name matches no object of the scene (``"banana"``, ``"gold block"`` among red, blue and yellow blocks);
3. the name fits several objects (``"block"`` among three blocks): the candidates are listed;
4. the grounder did not find the target (``MaskField.found`` is False), or its mask is empty;
5. the grounder's confidence (:attr:`abm.grounding.mask_field.MaskField.confidence`, reported by every
   grounder) is below ``min_confidence`` (:data:`MIN_CONFIDENCE`): several objects look about equally
   likely (CLIP's proposals give about ``1/k`` to ``k`` look-alikes).

Names are compared as :func:`normalize_name` forms: equal names first, else names that contain the target as
whole words (``"mug"`` -> ``"red mug"``), as the oracle grounder matches them.

Evaluation code logs the same decision per step with a :class:`GroundingRecorder` around the policy's
grounder::

    with GroundingRecorder(policy.grounder) as grounding:
        action = policy.act(observation, instruction, object_names)
        log["grounding"] = grounding.record()   # TargetDecision.as_record() of this step's answer, or None
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from abm.errors import ConfigError

if TYPE_CHECKING:
    from abm.grounding.mask_field import MaskField  # types only: mask_field.py loads torch

MIN_CONFIDENCE = 0.5
"""Smallest grounder confidence acted on: the chosen object at least as likely as all others together."""

_ARTICLES = ("a", "an", "the")


def normalize_name(name: str) -> str:
    """Canonical form for comparing object names: lower case, ``_``/``-`` as spaces, no articles."""
    words = re.sub(r"[_\-]+", " ", str(name).lower()).split()
    return " ".join(w for w in words if w not in _ARTICLES)


def scene_vocabulary(object_names: Mapping[int, str] | None) -> tuple[str, ...]:
    """The distinct object names of a scene, sorted (empty when the camera names no objects)."""
    return tuple(sorted({str(n) for n in (object_names or {}).values()}))


def target_candidates(target: str, object_names: Mapping[int, str] | None) -> tuple[str, ...]:
    """The scene's object names that ``target`` may mean, sorted: those equal to it (in :func:`normalize_name`
    form), else all that contain it as whole words. Empty when nothing matches (or the scene names nothing)."""
    want = normalize_name(target)
    names = scene_vocabulary(object_names)
    if not want:
        return ()
    exact = tuple(n for n in names if normalize_name(n) == want)
    if exact:
        return exact
    pattern = re.compile(rf"(^| ){re.escape(want)}( |$)")
    return tuple(n for n in names if pattern.search(normalize_name(n)))


@dataclass(frozen=True)
class TargetDecision:
    """Whether to act on the grounded target, and why not.

    Attributes:
        found: act on it: the target is one object of the scene and the grounder found it with confidence.
        confidence: the grounder's confidence in ``[0, 1]`` (:attr:`MaskField.confidence`); 1.0 when no grounder
            answer was judged and the name alone decided (0.0 when the name was refused).
        target: the object name X the instruction asks for.
        candidates: the scene's objects the name may mean (empty when it matches none, or the scene names none).
        reason: why it is refused (``""`` when ``found``).
        scene: the distinct object names the scene holds (empty for a real camera).
        grounder: the name of the grounder whose answer was judged (``""`` when none was).
    """

    found: bool
    confidence: float
    target: str
    candidates: tuple[str, ...]
    reason: str
    scene: tuple[str, ...] = ()
    grounder: str = ""

    def message(self, instruction: str, override: str | None = None) -> str:
        """One line for the user: what was refused, what the scene holds, the candidates and the fix.

        Args:
            instruction: the full instruction, quoted in the message.
            override: the option that acts anyway (``"--allow-no-target"``), named as the other way out.
        """
        held = f"the scene holds: {', '.join(self.scene)}" if self.scene else "the camera names no objects"
        cands = f"candidates: {', '.join(self.candidates)}" if self.candidates else "candidates: none"
        if len(self.candidates) > 1:
            fix = f"name one of {', '.join(repr(c) for c in self.candidates)}"
        elif not self.target or (self.scene and not self.candidates):
            fix = "name exactly one object the scene holds"
        else:  # the name is fine, the grounder's answer is not
            fix = ("make sure the object is in the cameras' view (abm ground shows what the grounder marks) or "
                   "describe it differently")
        out = f"no target to act on for {instruction!r}: {self.reason} ({held}; {cands}). Fix: {fix}"
        return out + (f", or pass {override} to act anyway" if override else "")

    def as_record(self) -> dict[str, Any]:
        """The decision as JSON-ready data (for ``steps.jsonl``, ``summary.json`` and evaluation logs)."""
        return {"found": self.found, "confidence": round(float(self.confidence), 4), "target": self.target,
                "candidates": list(self.candidates), "reason": self.reason, "scene": list(self.scene),
                "grounder": self.grounder}


def decide_target(field: MaskField | None, target: str | None, object_names: Mapping[int, str] | None = None,
                  *, min_confidence: float = MIN_CONFIDENCE, grounder: str = "") -> TargetDecision:
    """Decide whether ``field`` (a grounder's answer for ``target``) is a target to act on (module docstring).

    Args:
        field: the grounder's :class:`~abm.grounding.mask_field.MaskField` (``(N,)`` mask and heatmap, found,
            confidence), or ``None`` to judge the name alone against the scene (before any step, or for a
            policy that grounds nothing).
        target: the object name X (``None`` or blank: the instruction names none).
        object_names: segmentation id -> object name of the scene (``None`` or empty: not known, so no name check).
        min_confidence: the smallest confidence acted on, in ``[0, 1]``.
        grounder: the grounder's name, for the reason.

    Returns:
        The :class:`TargetDecision`; ``found`` is False with a ``reason`` when the target is refused.
    """
    if not 0.0 <= min_confidence <= 1.0:
        raise ConfigError(f"min_confidence must be in [0, 1], got {min_confidence}")
    name = " ".join(str(target or "").split())
    scene = scene_vocabulary(object_names)
    candidates = target_candidates(name, object_names)
    who = f"the {grounder} grounder" if grounder else "the grounder"

    def refuse(reason: str, confidence: float = 0.0) -> TargetDecision:
        return TargetDecision(False, confidence, name, candidates, reason, scene, grounder)

    if not name:
        return refuse("the instruction names no object to act on")
    if scene and not candidates:
        return refuse(f"{name!r} is not in the scene (no object has that name)")
    if len(candidates) > 1:
        return refuse(f"{name!r} could be any of {len(candidates)} objects")
    if field is None:
        return TargetDecision(True, 1.0, name, candidates, "", scene, grounder)
    confidence = float(getattr(field, "confidence", None) or 0.0)
    marked = int((np.asarray(field.mask) > 0.5).sum())
    if not field.found:
        guess = f"; the {marked} point(s) it marked are only a fallback guess" if marked else ""
        return refuse(f"{who} did not find {name!r}{guess}", confidence)
    if not marked:
        return refuse(f"{who} marked no point of {name!r}", confidence)
    if confidence < min_confidence:
        return refuse(f"{who} is not sure which object is {name!r} (confidence {confidence:.2f} < "
                      f"{min_confidence:.2f}: several objects look about equally likely)", confidence)
    return TargetDecision(True, confidence, name, candidates, "", scene, grounder)


@dataclass
class GroundingCall:
    """One ``grounder.ground(observation, cloud, target, object_names)`` call and its answer."""

    field: MaskField
    target: str
    object_names: dict[int, str]
    grounder: str = ""

    def decide(self, min_confidence: float = MIN_CONFIDENCE) -> TargetDecision:
        """:func:`decide_target` of this answer."""
        return decide_target(self.field, self.target, self.object_names, min_confidence=min_confidence,
                             grounder=self.grounder)


@dataclass
class GroundingRecorder:
    """Keeps the answers a grounder gives while the ``with`` block runs, so the code that drives a policy can
    judge the very mask the policy acted on (the policy grounds inside ``act`` / ``explain``).

    The grounder's ``ground`` method is wrapped on the instance for the block (the class is untouched) and
    restored on exit. ``None``, or a grounder whose method cannot be wrapped, records nothing (:attr:`last` stays
    None).

    Attributes:
        grounder: the grounder object (e.g. ``policy.grounder``), or ``None``.
        calls: the :class:`GroundingCall` s since the last :meth:`take` (or the start).
    """

    grounder: Any
    calls: list[GroundingCall] = field(default_factory=list)
    _wrapped: bool = field(default=False, repr=False)

    def __enter__(self) -> GroundingRecorder:
        original: Callable[..., Any] | None = getattr(self.grounder, "ground", None)
        if original is None:  # no grounder (a policy without one): nothing to record
            return self
        name = str(getattr(self.grounder, "name", "") or "")

        def ground(observation: Any, cloud: Any, target: str, object_names: Mapping[int, str] | None = None
                   ) -> Any:
            answer = original(observation, cloud, target, object_names)
            self.calls.append(GroundingCall(answer, str(target), dict(object_names or {}), name))
            return answer

        try:
            self.grounder.ground = ground
            self._wrapped = True
        except (AttributeError, TypeError):  # slots or a read-only attribute: nothing is recorded
            self._wrapped = False
        return self

    def __exit__(self, *exc: object) -> None:
        if self._wrapped:
            del self.grounder.ground  # the class's method again
            self._wrapped = False

    @property
    def last(self) -> GroundingCall | None:
        """The latest answer since the last :meth:`take`, or None."""
        return self.calls[-1] if self.calls else None

    def take(self) -> GroundingCall | None:
        """The latest answer, forgetting all recorded so far (call once per step)."""
        last = self.last
        self.calls.clear()
        return last

    def record(self, min_confidence: float = MIN_CONFIDENCE) -> dict[str, Any] | None:
        """The evaluation logs' helper: :meth:`TargetDecision.as_record` of the latest answer (:meth:`take`),
        or None when the grounder was not called (a policy variant without a mask)."""
        call = self.take()
        return None if call is None else call.decide(min_confidence).as_record()
