"""Keyframe actions <-> the discrete targets the policy predicts.

A :class:`~abm.types.KeyframeAction` is encoded as

* ``position``: ``(3,)`` float32 world metres (the translation heatmaps are built from it by projecting
  it into the views, see :func:`abm.policy.heads.translation_targets`),
* ``rotation_bins``: ``(3,)`` int64 bins of the extrinsic xyz Euler angles (``360 / bins`` degrees each),
* ``gripper``: 1 = open, 0 = closed,
* ``collision``: 1 = ignore collisions, 0 = avoid them.

Decoding gives back the same position, the rotation at the bin centres (exact for bin-centre
angles, within half a bin otherwise) and the two flags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from abm.geometry import bins_to_quat, quat_to_bins
from abm.types import KeyframeAction


@dataclass
class EncodedAction:
    """Discrete training targets of one keyframe (numpy; collated into batches of tensors)."""

    position: NDArray[np.float32]  # (3,) metres
    rotation_bins: NDArray[np.int64]  # (3,)
    gripper: int
    collision: int


def encode_action(action: KeyframeAction, rotation_bins: int = 72) -> EncodedAction:
    """:class:`KeyframeAction` -> :class:`EncodedAction`."""
    return EncodedAction(
        position=np.asarray(action.position, np.float32),
        rotation_bins=np.asarray(quat_to_bins(action.quaternion, rotation_bins), np.int64),
        gripper=int(action.gripper_open),
        collision=int(action.ignore_collision),
    )


def decode_action(
    position: np.ndarray, rotation_bins: np.ndarray, gripper: int, collision: int, num_bins: int = 72
) -> KeyframeAction:
    """Discrete predictions of one sample -> :class:`KeyframeAction`.

    Args:
        position: ``(3,)`` world metres.
        rotation_bins: ``(3,)`` Euler-angle bin per axis.
        gripper: 1 = open.
        collision: 1 = ignore collisions.
    """
    quat = bins_to_quat(np.asarray(rotation_bins, np.int64), num_bins)
    return KeyframeAction(np.asarray(position, np.float64), quat, bool(gripper), bool(collision))
