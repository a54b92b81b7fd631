"""Diagnoses: measurements that say why a policy scores what it scores, each a typed request.

A diagnosis is a frozen dataclass (a :class:`~abm.evaluation.diagnose.request.DiagnosisRequest`) whose fields
say what to measure (the model, tasks, scenes) and the file to write (``out``); ``request.run()`` measures,
writes that file and returns its content. Requests round-trip through JSON (``to_dict`` / :func:`from_dict`),
so the experiment engine hands them to a process or a Ray task, and the ``benchmarks/`` scripts that a person
runs by hand are command lines over the same requests.

The registry :data:`DIAGNOSES` names them (light: an entry holds its request class as ``"module:Class"``,
imported when it is used, :func:`abm.registry.resolve`):

* ``keyframe_accuracy``: a policy's keyframes against the scripted expert's, per keyframe kind
  (:class:`~abm.evaluation.diagnose.keyframe_accuracy.KeyframeAccuracy`);
* ``skill_text``: whether a mask policy's keyframe follows its skill text
  (:class:`~abm.evaluation.diagnose.skill_text.SkillTextProbe`);
* ``rotation_fit``: how well a policy fits the rotation labels of its training keyframes
  (:class:`~abm.evaluation.diagnose.rotation_fit.RotationFit`);
* ``failure_reasons``: why closed-loop rollouts stop, step by step against the expert
  (:class:`~abm.evaluation.diagnose.failure_reasons.FailureReasons`);
* ``destination_grounding``: how well a grounder finds each task's destination beside its target (of the grounder,
  not of a policy: :class:`~abm.evaluation.diagnose.destination_grounding.DestinationGrounding`).

**Adding a diagnosis**: its module (the request dataclass with its ``kind`` and ``run``) and its
:func:`register_diagnosis` entry here, plus its tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from abm.registry import Registry, resolve

if TYPE_CHECKING:
    from abm.evaluation.diagnose.request import DiagnosisRequest


@dataclass(frozen=True)
class DiagnosisKind:
    """One diagnosis: an entry of :data:`DIAGNOSES`.

    Attributes:
        request: ``"module:Class"`` of its request dataclass.
        description: one line (what it measures).
    """

    request: str
    description: str

    def request_class(self) -> type[DiagnosisRequest]:
        """The request dataclass (imported now)."""
        return resolve(self.request)  # type: ignore[no-any-return]


#: every diagnosis, by name (a request's ``kind``)
DIAGNOSES: Registry[DiagnosisKind] = Registry("diagnosis")


def register_diagnosis(name: str, kind: DiagnosisKind) -> DiagnosisKind:
    """Add a diagnosis to :data:`DIAGNOSES`."""
    return DIAGNOSES.register(name, kind)


def from_dict(data: dict[str, Any]) -> DiagnosisRequest:
    """The request a ``to_dict`` wrote, of the diagnosis its ``kind`` names.

    Raises:
        UnknownNameError: ``kind`` names no diagnosis (the message lists them).
        ConfigError: the fields do not fit that diagnosis' request.
    """
    return DIAGNOSES[data.get("kind")].request_class().from_dict(data)  # type: ignore[index]


register_diagnosis("keyframe_accuracy", DiagnosisKind(
    "abm.evaluation.diagnose.keyframe_accuracy:KeyframeAccuracy",
    "position, rotation and gripper error of a policy's keyframes against the expert's, per keyframe kind"))
register_diagnosis("skill_text", DiagnosisKind(
    "abm.evaluation.diagnose.skill_text:SkillTextProbe",
    "whether a mask policy's keyframe moves when its skill text changes"))
register_diagnosis("rotation_fit", DiagnosisKind(
    "abm.evaluation.diagnose.rotation_fit:RotationFit",
    "cross-entropy of a policy's rotation bins on its own training keyframes, beside chance and the prior"))
register_diagnosis("failure_reasons", DiagnosisKind(
    "abm.evaluation.diagnose.failure_reasons:FailureReasons",
    "why closed-loop rollouts stop: each step's motion status against the expert's keyframe, per kind"))
register_diagnosis("destination_grounding", DiagnosisKind(
    "abm.evaluation.diagnose.destination_grounding:DestinationGrounding",
    "point IoU, hit and found rate of a grounder's target and destination masks on evaluation scenes"))
