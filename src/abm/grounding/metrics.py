"""Grounding quality against ground-truth segmentation.

For one mask field over a cloud and the target's ground-truth points:

* **precision** = masked target points / masked points (NaN when the mask is empty);
* **recall** = masked target points / target points (NaN when the target is not visible);
* **center distance** (m) = distance from the mask centre (mean of the masked points) to the target
  centre (mean of the target points);
* **hit** = the mask centre lies inside the target points' axis-aligned bounding box grown by
  ``margin`` (default 1 cm) on every side — the property the center-pixel mask needs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np

DEFAULT_HIT_MARGIN = 0.01


@dataclass(frozen=True)
class GroundingScore:
    """Quality of one mask field (see the module docstring)."""

    precision: float
    recall: float
    center_distance: float
    hit: bool
    found: bool
    mask_points: int
    target_points: int

    def as_dict(self) -> dict[str, float | int | bool]:
        return asdict(self)


def score_mask(
    xyz: np.ndarray,
    mask: np.ndarray,
    target: np.ndarray,
    found: bool = True,
    margin: float = DEFAULT_HIT_MARGIN,
) -> GroundingScore:
    """Score a per-point mask.

    Args:
        xyz: ``(N, 3)`` point positions in metres.
        mask: ``(N,)`` predicted mask (values > 0.5 count as selected).
        target: ``(N,)`` bool ground-truth points of the target.
        found: the grounder's ``found`` flag (reported, not used in the other numbers).
        margin: growth of the target's bounding box for the hit test, metres.
    """
    xyz = np.asarray(xyz, np.float64)
    sel = np.asarray(mask).reshape(-1) > 0.5
    tgt = np.asarray(target, bool).reshape(-1)
    if sel.shape[0] != xyz.shape[0] or tgt.shape[0] != xyz.shape[0]:
        raise ValueError(f"mask ({sel.shape[0]}), target ({tgt.shape[0]}) and xyz ({xyz.shape[0]}) disagree")
    both = int((sel & tgt).sum())
    n_sel, n_tgt = int(sel.sum()), int(tgt.sum())
    precision = both / n_sel if n_sel else math.nan
    recall = both / n_tgt if n_tgt else math.nan
    if n_sel and n_tgt:
        center = xyz[sel].mean(0)
        tpts = xyz[tgt]
        distance = float(np.linalg.norm(center - tpts.mean(0)))
        hit = bool(np.all(center >= tpts.min(0) - margin) and np.all(center <= tpts.max(0) + margin))
    else:
        distance, hit = math.nan, False
    return GroundingScore(precision, recall, distance, hit, bool(found), n_sel, n_tgt)


def summarize(scores: Iterable[GroundingScore]) -> dict[str, float]:
    """Means over scores (NaN entries skipped): precision, recall, center distance, hit and found rates."""
    scores = list(scores)
    if not scores:
        return {"count": 0}

    def mean(values: list[float]) -> float:
        vals = [v for v in values if not math.isnan(v)]
        return float(np.mean(vals)) if vals else math.nan

    return {
        "count": len(scores),
        "precision": mean([s.precision for s in scores]),
        "recall": mean([s.recall for s in scores]),
        "center_distance_m": mean([s.center_distance for s in scores]),
        "hit_rate": float(np.mean([s.hit for s in scores])),
        "found_rate": float(np.mean([s.found for s in scores])),
    }
