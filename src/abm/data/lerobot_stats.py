"""The statistics of a LeRobot export: per episode (the ``stats/<feature>/<stat>`` columns of ``meta/episodes``)
and pooled over the dataset (``meta/stats.json``).

Each feature gets what LeRobot (0.6) computes and its normalisers read: ``min``, ``max``, ``mean``, ``std``,
``count`` and the quantiles ``q01``, ``q10``, ``q50``, ``q90``, ``q99`` (``NormalizationMode.QUANTILES`` scales
with q01 / q99, ``QUANTILE10`` with q10 / q90; pi0.5 uses the first for state and action). Shapes follow
LeRobot's: ``(3, 1, 1)`` per channel (values in [0, 1]) for cameras, per element for vectors and small arrays,
and (abm's choice, to keep the episode table small) one value over all pixels for depth and segmentation maps.

An episode's quantiles are exact (numpy's linear interpolation between the order statistics; LeRobot estimates
them from a 5000-bin histogram of a sample of the frames). The dataset's are pooled as LeRobot's
``aggregate_stats`` pools them: min of the minima, max of the maxima, the pooled mean and variance, and each
quantile the frame-count-weighted mean of the episodes' quantiles (exact for one episode, an approximation for
several, and what LeRobot itself writes when it merges episodes or datasets).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["PER_ELEMENT_STATS", "QUANTILES", "aggregate_stats", "feature_stats", "quantile_key"]

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
"""The quantiles LeRobot 0.6 computes (``lerobot.datasets.compute_stats.DEFAULT_QUANTILES``)."""
PER_ELEMENT_STATS = 16
"""Features of at most this many elements get stats per element; larger maps (depth, segmentation) one value."""


def quantile_key(q: float) -> str:
    """LeRobot's name of quantile ``q`` (a fraction): ``0.01`` -> ``"q01"``, ``0.5`` -> ``"q50"``."""
    return f"q{round(q * 100):02d}"


def feature_stats(feature: dict[str, Any], values: Any) -> dict[str, np.ndarray] | None:
    """One episode's statistics of a feature.

    Args:
        feature: the feature's ``info.json`` entry (``dtype``, ``shape``).
        values: its values for every frame of the episode: ``(n, H, W, 3)`` uint8 for a camera, ``(n, *shape)``
            otherwise (``(n,)`` for a scalar).

    Returns:
        ``min``, ``max``, ``mean``, ``std`` and the :data:`QUANTILES` (``q01`` ... ``q99``), each shaped as
        described in the module docstring, and ``count`` (``[n]``, frames). NaN values (unknown timestamps) are
        left out; ``None`` when nothing is left or the feature is text.
    """
    if feature["dtype"] == "string":
        return None
    v = np.asarray(values, np.float64)
    n = len(v)
    axes: tuple[int, ...] = (0,)
    if feature["dtype"] in ("video", "image"):
        v, axes, shape = v / 255.0, (0, 1, 2), [3, 1, 1]
    elif len(feature["shape"]) > 1 and math.prod(feature["shape"]) > PER_ELEMENT_STATS:
        v, shape = v.reshape(-1), [1]
    else:
        v, shape = v.reshape(n, -1), list(feature["shape"])
    nan = np.isnan(v)
    if nan.all():
        return None
    quantile = np.nanquantile if nan.any() else np.quantile  # nanquantile is several times slower
    with np.errstate(invalid="ignore"):
        result = {"min": np.nanmin(v, axis=axes), "max": np.nanmax(v, axis=axes), "mean": np.nanmean(v, axis=axes),
                  "std": np.nanstd(v, axis=axes)}
        qs = quantile(v, QUANTILES, axis=axes)
    result |= {quantile_key(q): qs[i] for i, q in enumerate(QUANTILES)}
    return {k: x.reshape(shape) for k, x in result.items()} | {"count": np.array([n], np.int64)}


def aggregate_stats(parts: list[dict[str, np.ndarray]]) -> dict[str, list[Any]]:
    """The dataset's statistics of a feature from its episodes' (:func:`feature_stats`), pooled as LeRobot's
    ``aggregate_stats`` pools them (see the module docstring), as JSON-ready lists."""
    counts = np.array([float(p["count"][0]) for p in parts])
    total = counts.sum()
    weights = counts.reshape(-1, *([1] * parts[0]["mean"].ndim))
    means = np.stack([p["mean"] for p in parts])
    mean = (means * weights).sum(0) / total
    var = ((np.stack([p["std"] for p in parts]) ** 2 + (means - mean) ** 2) * weights).sum(0) / total
    pooled = {"min": np.min([p["min"] for p in parts], axis=0), "max": np.max([p["max"] for p in parts], axis=0),
              "mean": mean, "std": np.sqrt(var)}
    for key in map(quantile_key, QUANTILES):
        pooled[key] = (np.stack([p[key] for p in parts]) * weights).sum(0) / total
    return {k: x.tolist() for k, x in pooled.items()} | {"count": [int(total)]}
