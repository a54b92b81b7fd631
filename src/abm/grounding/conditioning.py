"""Conditioning of an observation's fused cloud on an instruction: target X, skill text, per-point mask field.

The training data (:mod:`abm.data.keyframes`) and the policy at run time (:mod:`abm.policy`) both go
through :func:`condition_cloud`, so the two see the same points, mask and texts. Grounding results are
normalised to :class:`PointMask`.

**Sub-goals.** A two-target instruction ("put the ketchup in the bowl" -> X = ketchup, Y = bowl) is one
skill with two sub-goals: grasp X, then place it in Y. The policy always conditions on *one* mask, the
active sub-goal's: X while the gripper is open, Y once it has closed (:func:`active_role`). The rule
needs no extra label, so demonstrations and rollouts pick the same target at the same moments, and
one-target policies and checkpoints are unchanged.

**Destination.** Where the task brings X (the plate, the target pad, the wine rack; X itself for the jar a lid
closes; Y of a two-target instruction) is declared by each task (``Task.destination``);
:func:`abm.language.roles.destination_for` reads it for the tasks of an instruction's skill. With
``destination=True`` :func:`condition_cloud` grounds it with the same grounder into a second mask field
(:attr:`ConditionedCloud.destination_mask`; a grounder with a ``ground_destination`` method, the tracking one, keeps
a track of its own for it). An instruction whose tasks declare no destination (take_off_pan) gets an empty second
mask.

Grounders are configured by the typed configurations of :mod:`abm.grounding.config` (stored in checkpoints
as their dict form ``{"kind": "oracle"}``, ``{"kind": "clip", ...}`` or ``{"kind": "tracking", "inner": {...}}``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

from abm.geometry import PointCloud, Workspace, fuse_cameras
from abm.language.roles import instruction_destination, split_roles
from abm.types import Observation

if TYPE_CHECKING:
    from abm.grounding.feature_cloud import LiftedFeatures
    from abm.grounding.grounders import Grounder  # types only: grounders.py loads torch
    from abm.grounding.mask_field import MaskField


class PointFeatureGrounder(Protocol):
    """A grounder that also gives per-point CLIP features (the CLIP grounder; the tracking grounder passes its
    inner grounder's on). One that also has ``lifted_features`` (the CLIP grounder) gives them as the patch table
    they are lifted from (:class:`~abm.grounding.feature_cloud.LiftedFeatures`)."""

    def point_features(self, observation: Observation, cloud: PointCloud) -> np.ndarray: ...


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


def active_role(gripper_open: float, roles: int) -> int:
    """Index of the active sub-goal: the first (grasp X) while the gripper is open (``>= 0.5``), the second
    (place in Y) once it has closed; always 0 for one-target instructions."""
    return 0 if roles < 2 or float(gripper_open) >= 0.5 else 1


def ground_points(grounder: Grounder, observation: Observation, cloud: PointCloud, target: str,
                  object_names: Mapping[int, str]) -> PointMask:
    """Run a grounder and normalise its result to :class:`PointMask` (float32 arrays of length N)."""
    return _point_mask(grounder.ground(observation, cloud, target, dict(object_names)), cloud)


def ground_destination(grounder: Grounder, observation: Observation, cloud: PointCloud, destination: str | None,
                       object_names: Mapping[int, str]) -> PointMask:
    """The destination's mask field (:func:`ground_points` for the destination's name). A grounder with a
    ``ground_destination`` method (:class:`~abm.grounding.tracking.TrackingGrounder`: its own track, so the target's
    is kept) is asked through it; no destination gives an empty mask (``found`` False)."""
    if destination is None:
        empty = np.zeros(len(cloud), np.float32)
        return PointMask(empty, empty.copy(), False)
    ground = getattr(grounder, "ground_destination", grounder.ground)
    return _point_mask(ground(observation, cloud, destination, dict(object_names)), cloud)


def _point_mask(field: MaskField, cloud: PointCloud) -> PointMask:
    """A grounder's mask field (``mask``, optional ``heatmap`` and ``found``) as a :class:`PointMask`."""
    mask = np.asarray(field.mask, np.float32).reshape(-1)
    heat = getattr(field, "heatmap", None)
    heat = mask.copy() if heat is None else np.asarray(heat, np.float32).reshape(-1)
    if mask.shape[0] != len(cloud) or heat.shape[0] != len(cloud):
        raise ValueError(f"grounder returned {mask.shape[0]} mask values for a cloud of {len(cloud)} points")
    found = bool(getattr(field, "found", mask.any()))
    return PointMask(mask, np.clip(heat, 0.0, 1.0), found)


@dataclass
class ConditionedCloud:
    """One observation fused into a point cloud and conditioned on an instruction.

    Attributes:
        cloud: the fused, workspace-cropped point cloud (``N`` points).
        instruction: the full instruction.
        target: the active sub-goal's object (X, or Y once the gripper has closed on X; ``None`` when not
            split).
        skill: the skill text with X replaced by ``"X"`` (``None`` when not split).
        point_mask: the mask field over the cloud's points (``None`` unless asked for).
        features: the per-point CLIP features as a table and each point's row in it (``None`` unless asked for).
        role: index of the active sub-goal (:func:`active_role`).
        destination: the destination object's name (:func:`~abm.language.roles.destination_for`; ``None``: none, or
            not asked for).
        destination_mask: the destination's mask field over the cloud's points (``None`` unless asked for).
    """

    cloud: PointCloud
    instruction: str
    target: str | None
    skill: str | None
    point_mask: PointMask | None
    features: LiftedFeatures | None
    role: int = 0
    destination: str | None = None
    destination_mask: PointMask | None = None


def condition_cloud(
    observation: Observation,
    instruction: str,
    workspace: Workspace,
    *,
    grounder: Grounder | None = None,
    object_names: Mapping[int, str] | None = None,
    split: bool = True,
    target: str | tuple[str, ...] | None = None,
    skill: str | None = None,
    mask: bool = False,
    features: bool = False,
    camera_names: list[str] | None = None,
    destination: bool = False,
    destination_name: str | None = None,
) -> ConditionedCloud:
    """Fuse the cameras inside ``workspace`` and condition the cloud on ``instruction``.

    Args:
        observation: cameras and gripper state.
        instruction: the full English instruction.
        workspace: crop cube of the fused cloud.
        grounder: grounder object (needed when ``mask`` or ``features``).
        object_names: segmentation id -> object name (the oracle grounder needs them).
        split: split the instruction into ``(X, skill text)`` with :func:`~abm.language.roles.split_roles` unless
            ``target`` and ``skill`` are given (a dataset splits each episode's instruction once).
        target / skill: the already known split; ``target`` may be the tuple of the sub-goals' objects,
            of which the active one (:func:`active_role`) is grounded.
        mask: compute the mask field of X over the cloud.
        features: compute per-point CLIP features (the grounder must have ``point_features``: CLIP, tracking).
        camera_names: cameras to fuse (default all).
        destination: also ground the destination into a second mask field (:attr:`ConditionedCloud.destination_mask`).
        destination_name: the destination's name when known (a dataset's ground truth); default the instruction's
            (:func:`~abm.language.roles.instruction_destination`).

    Raises:
        ValueError: no target in the instruction (when splitting), or no grounder for ``mask`` /
            ``features``.
    """
    cloud = fuse_cameras(observation, workspace, camera_names)
    if (split or mask) and (target is None or skill is None):
        target, skill = split_roles(instruction, object_names)
    role = 0
    roles = target if isinstance(target, tuple) else (target,) if target is not None else ()
    if isinstance(target, tuple):
        role = active_role(observation.gripper_open, len(target))
        target = target[role]
    if destination and destination_name is None:
        destination_name = instruction_destination(instruction, roles or None)
    if (mask or features or destination) and grounder is None:
        raise ValueError("a grounder is needed for the mask field and CLIP point features")
    point_mask = None
    if mask:
        assert grounder is not None and target is not None  # checked above; split_roles always gives a target
        point_mask = ground_points(grounder, observation, cloud, target, object_names or {})
    feats = None
    if features:
        feats = point_feature_table(cast("PointFeatureGrounder", grounder), observation, cloud)
    destination_mask = None
    if destination:
        assert grounder is not None  # checked above
        destination_mask = ground_destination(grounder, observation, cloud, destination_name, object_names or {})
    return ConditionedCloud(cloud, instruction, target, skill, point_mask, feats, role,
                            destination_name if destination else None, destination_mask)


def point_feature_table(grounder: PointFeatureGrounder, observation: Observation, cloud: PointCloud
                        ) -> LiftedFeatures:
    """The grounder's per-point CLIP features of ``cloud`` as a float32 table and each point's row in it: its
    ``lifted_features`` when it has them (the CLIP grounder, also through a tracking grounder), else its
    ``point_features`` with one row per point."""
    from abm.grounding.feature_cloud import LiftedFeatures  # torch-backed module: only when features are asked for

    lifted = getattr(grounder, "lifted_features", None)
    found = lifted(observation, cloud) if lifted is not None else grounder.point_features(observation, cloud)
    if isinstance(found, LiftedFeatures):
        return LiftedFeatures(np.asarray(found.table, np.float32), found.index)
    return LiftedFeatures.per_point(np.asarray(found, np.float32))
