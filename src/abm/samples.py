"""The keyframe sample: what the data pipeline hands a policy, independent of the policy.

A sample is a dict. Scene entries (training and inference):

* ``points`` ``(N, 3)`` float32, world metres (after augmentation in training);
* ``colors`` ``(N, 3)`` float32 in ``[0, 1]``;
* ``point_mask`` / ``point_heatmap`` ``(N,)`` float32: the mask field of the target X (only when asked for);
* ``destination_mask`` / ``destination_heatmap`` ``(N,)`` float32: the mask field of the destination (the plate, the
  target pad, ...; all zeros for a task without one; only when asked for);
* ``feature_table`` ``(P, F)`` float16 and ``feature_row`` ``(N,)`` int32: per-point CLIP features (only when
  asked for), point ``i``'s being ``feature_table[feature_row[i]]`` (a CLIP grounder's table holds the camera
  patches, a few hundred rows that a scene's ~50k points share; features that are no patch lookup, such as a
  mean over several CLIP input sizes, have one row per point);
* ``gripper_open`` ``()`` float32 (1 = open) and ``gripper_position`` ``(3,)`` float32, world metres;
* ``keyframe_index`` ``()`` int64: the observation's keyframe index in its episode (``Observation.step``: 0 at the
  start, one more per executed keyframe, in demonstrations and rollouts alike);
* ``instruction`` and ``skill`` (``str``; ``skill`` is the instruction with X replaced by ``"X"``, or ``""``
  when the instruction was not split).

Training targets (the keyframe to reach): ``action_position`` ``(3,)`` float32 metres,
``action_quaternion`` ``(4,)`` float64 ``(x, y, z, w)``, ``action_gripper`` int64 (1 = open),
``action_collision`` int64 (1 = ignore collisions).

:func:`collate` stacks samples into a batch: point arrays are zero-padded to the longest cloud and a
``valid`` ``(B, N)`` bool marks the real points (padded ``feature_row`` entries are 0); feature tables are
zero-padded to the longest; strings become lists. The policy renders the batch
itself (:class:`abm.policy.KeyframePolicy`), on its own device.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NotRequired, TypedDict, cast

import numpy as np
import torch

from abm.grounding.conditioning import ConditionedCloud
from abm.types import KeyframeAction

POINT_KEYS = ("points", "colors", "point_mask", "point_heatmap", "feature_row", "destination_mask",
              "destination_heatmap")
TABLE_KEYS = ("feature_table",)
TEXT_KEYS = ("instruction", "skill")


class ActionTargets(TypedDict):
    """The training-target entries of a sample (see module docstring)."""

    action_position: torch.Tensor
    action_quaternion: torch.Tensor
    action_gripper: torch.Tensor
    action_collision: torch.Tensor


class Sample(TypedDict):
    """One keyframe sample (see module docstring); the optional entries are there when asked for."""

    points: torch.Tensor
    colors: torch.Tensor
    gripper_open: torch.Tensor
    gripper_position: torch.Tensor
    instruction: str
    skill: str
    point_mask: NotRequired[torch.Tensor]
    point_heatmap: NotRequired[torch.Tensor]
    feature_table: NotRequired[torch.Tensor]
    feature_row: NotRequired[torch.Tensor]
    destination_mask: NotRequired[torch.Tensor]
    destination_heatmap: NotRequired[torch.Tensor]
    keyframe_index: NotRequired[torch.Tensor]
    action_position: NotRequired[torch.Tensor]
    action_quaternion: NotRequired[torch.Tensor]
    action_gripper: NotRequired[torch.Tensor]
    action_collision: NotRequired[torch.Tensor]


class Batch(TypedDict):
    """Samples stacked by :func:`collate`: a leading batch axis, point arrays zero-padded, texts as lists."""

    points: torch.Tensor
    colors: torch.Tensor
    gripper_open: torch.Tensor
    gripper_position: torch.Tensor
    instruction: list[str]
    skill: list[str]
    valid: NotRequired[torch.Tensor]  # (B, N) real points; always set by collate
    point_mask: NotRequired[torch.Tensor]
    point_heatmap: NotRequired[torch.Tensor]
    feature_table: NotRequired[torch.Tensor]
    feature_row: NotRequired[torch.Tensor]
    destination_mask: NotRequired[torch.Tensor]
    destination_heatmap: NotRequired[torch.Tensor]
    keyframe_index: NotRequired[torch.Tensor]
    action_position: NotRequired[torch.Tensor]
    action_quaternion: NotRequired[torch.Tensor]
    action_gripper: NotRequired[torch.Tensor]
    action_collision: NotRequired[torch.Tensor]


def cloud_sample(conditioned: ConditionedCloud, gripper_open: float, gripper_position: np.ndarray,
                 points: np.ndarray | None = None, keyframe_index: int = 0) -> Sample:
    """The point-cloud entries of a sample.

    Args:
        conditioned: the conditioned observation.
        gripper_open: gripper opening in ``[0, 1]``.
        gripper_position: ``(3,)`` world metres (after augmentation in training).
        points: ``(N, 3)`` replacement point positions (the augmented cloud); default the conditioned cloud's.
        keyframe_index: the observation's keyframe index in its episode (``Observation.step``).
    """
    xyz = conditioned.cloud.xyz if points is None else points
    sample: Sample = {
        "points": torch.from_numpy(np.ascontiguousarray(xyz, np.float32)),
        "colors": torch.from_numpy(np.ascontiguousarray(conditioned.cloud.rgb, np.float32)),
        "gripper_open": torch.tensor(float(gripper_open), dtype=torch.float32),
        "gripper_position": torch.from_numpy(np.asarray(gripper_position, np.float32).reshape(3)),
        "instruction": conditioned.instruction,
        "skill": conditioned.skill or "",
        "keyframe_index": torch.tensor(int(keyframe_index), dtype=torch.int64),
    }
    if conditioned.point_mask is not None:
        sample["point_mask"] = torch.from_numpy(np.asarray(conditioned.point_mask.mask, np.float32))
        sample["point_heatmap"] = torch.from_numpy(np.asarray(conditioned.point_mask.heatmap, np.float32))
    if conditioned.destination_mask is not None:
        sample["destination_mask"] = torch.from_numpy(np.asarray(conditioned.destination_mask.mask, np.float32))
        sample["destination_heatmap"] = torch.from_numpy(np.asarray(conditioned.destination_mask.heatmap, np.float32))
    if conditioned.features is not None:
        sample["feature_table"] = torch.from_numpy(np.asarray(conditioned.features.table, np.float16))
        sample["feature_row"] = torch.from_numpy(np.asarray(conditioned.features.index, np.int32))
    return sample


def action_targets(action: KeyframeAction) -> ActionTargets:
    """The training-target entries of a sample for the keyframe ``action``."""
    return {
        "action_position": torch.from_numpy(np.asarray(action.position, np.float32)),
        "action_quaternion": torch.from_numpy(np.asarray(action.quaternion, np.float64)),
        "action_gripper": torch.tensor(int(action.gripper_open), dtype=torch.int64),
        "action_collision": torch.tensor(int(action.ignore_collision), dtype=torch.int64),
    }


def collate(samples: Sequence[Sample]) -> Batch:
    """Stack samples into a batch (see module docstring); ``valid`` ``(B, N)`` marks real points."""
    if not samples:
        raise ValueError("cannot collate an empty list of samples")
    sizes = [int(s["points"].shape[0]) for s in samples]
    n = max(max(sizes), 1)
    rows: Sequence[Mapping[str, Any]] = samples  # every key is handled alike, by its kind
    out: dict[str, Any] = {}
    for key in rows[0]:
        vals = [s[key] for s in rows]
        if key in TEXT_KEYS:
            out[key] = list(vals)
        elif key in POINT_KEYS or key in TABLE_KEYS:
            length = n if key in POINT_KEYS else max(int(v.shape[0]) for v in vals)
            padded = vals[0].new_zeros((len(vals), length, *vals[0].shape[1:]))
            for i, v in enumerate(vals):
                padded[i, : v.shape[0]] = v
            out[key] = padded
        else:
            out[key] = torch.stack(vals)
    valid = torch.zeros(len(samples), n, dtype=torch.bool)
    for i, size in enumerate(sizes):
        valid[i, :size] = True
    out["valid"] = valid
    return cast(Batch, out)
