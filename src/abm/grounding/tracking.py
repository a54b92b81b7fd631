"""Ground the target once, then track its 3-D points (the paper's proposed fix for its limitation 1).

The per-step grounders rebuild the Object Mask Field at every keyframe: slow with CLIP, and the
identified target can jump to another object between steps. :class:`TrackingGrounder` runs its inner
grounder on the first step of an episode (or when the target changes, or when tracking is lost) and
afterwards carries the target's points forward:

1. **Motion.** The target either stayed where it was or, when the gripper was closed at the previous
   step, moved with the gripper (the tracked points moved by ``T_now @ inv(T_prev)``, so a grasped object
   is followed up to its release). Both hypotheses are fitted and the one that finds more of the target
   is kept, so a target that is not the held object (the jar while the lid is carried) stays put.
2. **Correction.** A few translation-only ICP iterations (median offset to the nearest new points, within
   ``2 * radius``) absorb small unmodelled motion: an object dropped onto its support, a slip.
3. **Association.** A point of the new cloud belongs to the target when it lies within ``radius`` (m)
   of a tracked point (``scipy.spatial.cKDTree``). The tracked points stay the ones the inner grounder
   found, moved rigidly; new points are never added to them, so the mask cannot drift onto the fingers.
4. **Loss of track.** A tracked point is found when a new point within ``2 * radius`` has nearly its
   colour (every channel within ``color_tol``). When fewer than ``min_kept`` are found (occlusion, the
   object taken away, a wrong motion assumption), the inner grounder runs again.
5. **Re-acquisition** (``reacquire=True``; off by default: with the proposal grounder's good first answers
   it lowered tracked IoU, 0.71 -> 0.61, docs/grounding.md section 5). It is for grounders whose first
   answer is often wrong, which tracking would otherwise keep for the whole episode. While tracking, the
   inner grounder also runs, and its heatmap scores the tracked target (mean over the tracked mask) and its own
   answer (mean over its mask). When the tracked target's score falls below ``reacquire_ratio`` times the
   fresh answer's, the fresh answer replaces the track. Otherwise the tracked mask is kept: a small
   hysteresis against answers that jump from step to step. This costs one inner call per step.

Call :meth:`TrackingGrounder.reset` between episodes (``KeyframePolicy.reset`` does).

The destination (the policy's second mask, :func:`abm.grounding.conditioning.ground_destination`) is tracked
the same way in a track of its own (:meth:`TrackingGrounder.ground_destination`), so grounding it at every step
does not make the target's track start over.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from abm.errors import ConfigError
from abm.geometry import PointCloud
from abm.grounding.config import TrackingGrounderConfig, build_grounder
from abm.grounding.mask_field import MaskField
from abm.types import Observation

if TYPE_CHECKING:
    from abm.grounding.grounders import Grounder  # types only: grounders.py loads torch and CLIP

_DEFAULTS = TrackingGrounderConfig()  # the defaults' one source


@dataclass
class _Track:
    target: str
    points: np.ndarray  # (M, 3) world metres: the grounded target points, moved to the last step
    colors: np.ndarray  # (M, 3) their colours in [0, 1]
    gripper_pose: np.ndarray  # (4, 4) at the last step
    gripper_closed: bool
    confidence: float  # the inner grounder's confidence in the answer the track started from, in [0, 1]


class TrackingGrounder:
    """Ground with ``inner`` once per episode and target, then track the target's points.

    Args:
        inner: any grounder (``ground(observation, cloud, target, object_names) -> MaskField``).
        radius: association distance in metres (a point within it of a predicted target point is target).
        min_kept: share of the predicted target points that must find a new point, else re-ground.
        closed_below: gripper opening under which the gripper counts as closed (holding).
        color_tol: largest per-channel colour difference of a found point (colours in ``[0, 1]``).
        reacquire: re-score the tracked target with the inner grounder at every step and switch to its answer
            when the tracked target's score falls (see the module docstring); needs a graded heatmap (CLIP).
        reacquire_ratio: switch when the tracked target's mean heatmap is below this share of the fresh
            answer's.

    Attributes:
        inner_calls: how often the inner grounder ran (for tests and the tracking benchmark).
    """

    name = "tracking"

    def __init__(self, inner: Grounder, radius: float = _DEFAULTS.radius, min_kept: float = _DEFAULTS.min_kept,
                 closed_below: float = _DEFAULTS.closed_below, color_tol: float = _DEFAULTS.color_tol,
                 reacquire: bool = _DEFAULTS.reacquire, reacquire_ratio: float = _DEFAULTS.reacquire_ratio) -> None:
        if radius <= 0 or not 0 < min_kept <= 1 or color_tol <= 0:
            raise ConfigError(f"radius and color_tol must be > 0 and min_kept in (0, 1], got {radius}, "
                              f"{color_tol}, {min_kept}")
        if not 0 < reacquire_ratio <= 1:
            raise ConfigError(f"reacquire_ratio must be in (0, 1], got {reacquire_ratio}")
        self.inner = inner
        self.reacquire = bool(reacquire)
        self.reacquire_ratio = reacquire_ratio
        self.reacquired = 0  # times a fresh answer replaced the track
        self.radius, self.min_kept, self.closed_below, self.color_tol = radius, min_kept, closed_below, color_tol
        self.inner_calls = 0
        self._tracks: dict[str, _Track] = {}  # "target" and "destination": one track each

    @classmethod
    def from_config(cls, config: TrackingGrounderConfig, **runtime: Any) -> TrackingGrounder:
        """The grounder of a typed configuration (:data:`abm.grounding.config.GROUNDERS`' builder); ``runtime``
        goes to the inner grounder."""
        return cls(build_grounder(config.inner, **runtime), radius=config.radius, min_kept=config.min_kept,
                   closed_below=config.closed_below, color_tol=config.color_tol, reacquire=config.reacquire,
                   reacquire_ratio=config.reacquire_ratio)

    def reset(self) -> None:
        """Forget the tracked target and destination (call at the start of every episode)."""
        self._tracks.clear()

    def __getattr__(self, name: str) -> Any:  # point_features, text_features, ... of the inner grounder
        if name.startswith("_") or name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _found(self, tree: cKDTree, cloud: PointCloud, points: np.ndarray, colors: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """Which tracked points have a same-coloured new point within ``2 * radius``, and its index."""
        dist, index = tree.query(points, distance_upper_bound=2 * self.radius)
        found = np.isfinite(dist)
        found[found] &= np.abs(cloud.rgb[index[found]] - colors[found]).max(-1) <= self.color_tol
        return found, index

    def _fit(self, tree: cKDTree, cloud: PointCloud, points: np.ndarray, colors: np.ndarray
             ) -> tuple[float, np.ndarray]:
        """Translation-only ICP of the tracked points onto the new cloud: ``(share found, moved points)``."""
        for _ in range(3):
            found, index = self._found(tree, cloud, points, colors)
            if found.mean() < self.min_kept:
                break
            points = points + np.median(cloud.xyz[index[found]] - points[found], axis=0)
        found, _ = self._found(tree, cloud, points, colors)
        return float(found.mean()), points

    def ground(
        self,
        observation: Observation,
        cloud: PointCloud,
        target: str,
        object_names: Mapping[int, str] | None = None,
    ) -> MaskField:
        """The target's mask field: tracked from the last step, or the inner grounder's (module docstring)."""
        return self._ground("target", observation, cloud, target, object_names)

    def ground_destination(self, observation: Observation, cloud: PointCloud, destination: str,
                           object_names: Mapping[int, str] | None = None) -> MaskField:
        """The destination's mask field, tracked like the target's in a track of its own."""
        return self._ground("destination", observation, cloud, destination, object_names)

    def _ground(self, slot: str, observation: Observation, cloud: PointCloud, target: str,
                object_names: Mapping[int, str] | None) -> MaskField:
        closed = float(observation.gripper_open) < self.closed_below
        pose = np.asarray(observation.gripper_pose, np.float64)
        track = self._tracks.get(slot)
        if track is not None and track.target == target and len(track.points) and len(cloud):
            tree = cKDTree(cloud.xyz)
            hypotheses = [track.points]  # the target stayed where it was
            if track.gripper_closed:  # or it moved with the gripper (if the gripper held it, not another object)
                motion = pose @ np.linalg.inv(track.gripper_pose)
                hypotheses.append(track.points @ motion[:3, :3].T + motion[:3, 3])
            share, predicted = max((self._fit(tree, cloud, h, track.colors) for h in hypotheses), key=lambda r: r[0])
            if share >= self.min_kept:
                near, _ = cKDTree(predicted).query(cloud.xyz, distance_upper_bound=self.radius)
                mask = np.isfinite(near).astype(np.float32)
                fresh = self._rescore(observation, cloud, target, object_names, mask) if self.reacquire else None
                if fresh is None:
                    self._tracks[slot] = _Track(target, predicted, track.colors, pose, closed, track.confidence)
                    # as sure as the first answer, scaled by the share of its points still found
                    return MaskField(mask, mask.copy(), bool(mask.any()), target, "",
                                     confidence=track.confidence * share)
                self.reacquired += 1
                return self._start(slot, fresh, cloud, target, pose, closed)
        field = self.inner.ground(observation, cloud, target, object_names)
        self.inner_calls += 1
        return self._start(slot, field, cloud, target, pose, closed)

    def _rescore(self, observation: Observation, cloud: PointCloud, target: str,
                 object_names: Mapping[int, str] | None, tracked: np.ndarray) -> MaskField | None:
        """The inner grounder's fresh answer when the tracked target scores below ``reacquire_ratio`` times it
        (mean heatmap over each mask), else None (keep the track)."""
        fresh = self.inner.ground(observation, cloud, target, object_names)
        self.inner_calls += 1
        heat, own = np.asarray(fresh.heatmap), np.asarray(fresh.mask) > 0.5
        keep = tracked > 0.5
        if not own.any() or not keep.any():
            return None
        return fresh if heat[keep].mean() < self.reacquire_ratio * heat[own].mean() else None

    def _start(self, slot: str, field: MaskField, cloud: PointCloud, target: str, pose: np.ndarray,
               closed: bool) -> MaskField:
        """Start the track of ``slot`` from a grounder's answer and return it."""
        keep = np.asarray(field.mask) > 0.5
        if keep.any():
            self._tracks[slot] = _Track(target, cloud.xyz[keep], cloud.rgb[keep], pose, closed,
                                        float(field.confidence or 0.0))
        else:
            self._tracks.pop(slot, None)
        return field
