"""Object Mask Field: a per-point heatmap of "how much is this point the target", and its 0/1 mask.

1. **Similarity**: cosine of every point feature with the text feature of the prompt
   ``"a photo of a X"`` (both unit length, so a dot product), in ``[-1, 1]``.
2. **Normalisation** (:func:`normalize_heatmap`), because raw MaskCLIP cosines are small (about
   0.1-0.3 for real CLIP) and a fixed threshold of 0.7 on them selects nothing:

   * ``raw``: the cosine itself.
   * ``minmax``: ``(s - min) / (max - min)`` over the points of this cloud. Always marks the
     best-scoring region, even when the object is absent.
   * ``softmax`` (default): per point, a softmax over the target prompt and negative prompts
     (``"a photo of an object"``, ``... things``, ``... stuff``, ``... texture``) with temperature
     ``logit_scale`` (CLIP's 100); the heatmap is the target's probability. A point passes only when it
     looks more like X than like generic stuff, so an absent object can be reported as not found.
3. **Threshold** (default 0.7): heatmap ``>= threshold`` -> 1.0, else 0.0. When nothing passes, the
   documented fallback keeps the ``fallback_top_k`` highest-scoring points (``fallback="top"``) or leaves
   the mask empty (``fallback="none"``); :attr:`MaskField.found` is False in both cases.
4. **Virtual views** (:func:`mask_views`): the 0/1 point mask is rendered into the 5 orthographic views
   and post-processed into center-pixel masks (plus the soft and binarised ablation variants).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import torch

from abm.grounding.config import (  # the options and their defaults live with the typed configurations
    DEFAULT_LOGIT_SCALE,
    DEFAULT_NORMALIZATION,
    DEFAULT_THRESHOLD,
    NORMALIZATIONS,
    MaskFieldConfig,
)
from abm.language.instruction import clip_prompt
from abm.render import binarize_mask, center_pixel_mask, soft_mask

if TYPE_CHECKING:
    from abm.geometry import PointCloud
    from abm.render import OrthographicRenderer

@dataclass
class MaskField:
    """The grounding result for one observation and one target.

    Attributes:
        mask: ``(N,)`` float32, 1.0 for points of the target, per point of the cloud it was computed on.
        heatmap: ``(N,)`` float32 normalised score (``[0, 1]`` for ``minmax``/``softmax``).
        found: True when some point passed the threshold (False when the mask is a fallback or empty).
        target: the object description X.
        prompt: the text prompt used (empty for the oracle).
        similarity: ``(N,)`` float32 raw cosine similarity, when computed from features.
        confidence: in ``[0, 1]``, how sure the grounder is that the mask is the target: 0.0 when not
            ``found``. Every grounder reports one: the oracle 1.0; CLIP's per-point field the mean softmax
            heatmap over the masked points (1.0 for ``raw`` cosines, which have no probability); CLIP's
            proposals the best candidate's softmax probability among all candidates (about ``1/k`` when
            ``k`` objects are equally likely); tracking the first answer's confidence times the share of the
            target's points still found. Left out (``None``), it is :func:`mask_confidence` of the field.
    """

    mask: np.ndarray
    heatmap: np.ndarray
    found: bool
    target: str = ""
    prompt: str = ""
    similarity: np.ndarray | None = field(default=None, repr=False)
    confidence: float | None = None

    def __post_init__(self) -> None:
        self.mask = np.asarray(self.mask, np.float32)
        self.heatmap = np.asarray(self.heatmap, np.float32)
        if self.mask.ndim != 1 or self.mask.shape != self.heatmap.shape:
            raise ValueError(f"mask and heatmap must both be (N,), got {self.mask.shape} and {self.heatmap.shape}")
        self.found = bool(self.found)
        if self.confidence is None:
            self.confidence = mask_confidence(self.mask, self.heatmap, self.found)
        value = float(self.confidence)
        self.confidence = min(max(value, 0.0), 1.0) if self.found and np.isfinite(value) else 0.0

    def __len__(self) -> int:
        return int(self.mask.shape[0])

    def center(self, xyz: np.ndarray) -> np.ndarray | None:
        """``(3,)`` mean position (m) of the masked points of ``xyz`` ``(N, 3)``, or None if the mask is empty."""
        sel = self.mask > 0.5
        return np.asarray(xyz)[sel].mean(0) if sel.any() else None


def mask_confidence(mask: np.ndarray, heatmap: np.ndarray, found: bool) -> float:
    """The default :attr:`MaskField.confidence`: the mean heatmap (clipped to ``[0, 1]``) over the masked points
    of ``mask`` ``(N,)``, 0.0 when not ``found`` or nothing is masked (the oracle's 0/1 heatmap gives 1.0)."""
    selected = np.asarray(mask) > 0.5
    if not found or not selected.any():
        return 0.0
    return float(np.clip(np.asarray(heatmap, np.float64)[selected], 0.0, 1.0).mean())


def normalize_heatmap(
    similarity: np.ndarray | torch.Tensor,
    mode: str = DEFAULT_NORMALIZATION,
    negative_similarity: np.ndarray | torch.Tensor | None = None,
    logit_scale: float = DEFAULT_LOGIT_SCALE,
) -> np.ndarray:
    """Normalise cosine similarities ``(N,)`` into a heatmap ``(N,)`` float32.

    Args:
        similarity: cosine with the target prompt per point.
        mode: ``"raw"``, ``"minmax"`` or ``"softmax"``.
        negative_similarity: ``(N, K)`` cosines with the K negative prompts (``softmax`` only).
        logit_scale: softmax temperature multiplier.
    """
    sim = torch.as_tensor(similarity, dtype=torch.float32).reshape(-1)
    if mode == "raw":
        out = sim
    elif mode == "minmax":
        if sim.numel() == 0:
            out = sim
        else:
            lo, hi = sim.min(), sim.max()
            out = (sim - lo) / (hi - lo) if hi > lo else torch.zeros_like(sim)
    elif mode == "softmax":
        if negative_similarity is None:
            raise ValueError("softmax normalisation needs the similarities with the negative prompts")
        neg = torch.as_tensor(negative_similarity, dtype=torch.float32).reshape(sim.shape[0], -1)
        logits = torch.cat([sim[:, None], neg], dim=1) * float(logit_scale)
        out = torch.softmax(logits, dim=1)[:, 0]
    else:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {mode!r}")
    return out.numpy().astype(np.float32)


def threshold_heatmap(
    heatmap: np.ndarray,
    threshold: float = DEFAULT_THRESHOLD,
    fallback: str = "top",
    fallback_top_k: int = 1,
) -> tuple[np.ndarray, bool]:
    """Heatmap ``(N,)`` -> ``(mask (N,) float32 0/1, found)``.

    ``found`` is True when at least one point is ``>= threshold``. Otherwise the mask holds the
    ``fallback_top_k`` highest-scoring points (``fallback="top"``) or nothing (``"none"``).
    """
    heatmap = np.asarray(heatmap, np.float32).reshape(-1)
    passed = heatmap >= threshold
    if passed.any():
        return passed.astype(np.float32), True
    mask = np.zeros_like(heatmap)
    if fallback == "top" and heatmap.size:
        k = min(int(fallback_top_k), heatmap.size)
        mask[np.argpartition(-heatmap, k - 1)[:k]] = 1.0
    elif fallback not in ("top", "none"):
        raise ValueError(f"fallback must be 'top' or 'none', got {fallback!r}")
    return mask, False


def mask_field_from_features(
    point_features: np.ndarray | torch.Tensor,
    text_feature: np.ndarray | torch.Tensor,
    negative_features: np.ndarray | torch.Tensor | None = None,
    config: MaskFieldConfig | None = None,
    target: str = "",
    prompt: str = "",
) -> MaskField:
    """Compute the mask field from unit-length point features ``(N, D)`` and text feature ``(D,)``.

    ``negative_features`` ``(K, D)`` are the negative prompts' features (needed for ``softmax``).
    """
    config = config or MaskFieldConfig()
    feats = torch.as_tensor(point_features, dtype=torch.float32)
    text = torch.as_tensor(text_feature, dtype=torch.float32).reshape(-1)
    if feats.ndim != 2 or feats.shape[1] != text.shape[0]:
        raise ValueError(f"point features (N, D) and text feature (D,) disagree: {tuple(feats.shape)}, "
                         f"{tuple(text.shape)}")
    sim = feats @ text
    neg = None
    if config.normalization == "softmax":
        if negative_features is None:
            raise ValueError("softmax normalisation needs negative_features")
        neg = feats @ torch.as_tensor(negative_features, dtype=torch.float32).reshape(-1, text.shape[0]).T
    heat = normalize_heatmap(sim, config.normalization, neg, config.logit_scale)
    mask, found = threshold_heatmap(heat, config.threshold, config.fallback, config.fallback_top_k)
    confidence = float(found) if config.normalization == "raw" else None  # raw cosines are no probability
    return MaskField(mask, heat, found, target, prompt, sim.numpy().astype(np.float32), confidence)


@dataclass
class MaskViews:
    """The mask rendered into the virtual views, in the three forms compared by the paper.

    All tensors are ``(V, H, W)`` float32 on the renderer's device.

    Attributes:
        center: center-pixel masks (one 1.0 per view at the centre of the mask region; the method).
        soft: the re-rendered mask (ablation ``concat-rerendered``; 0/1 here, fractional when the
            rendered channel is a soft heatmap).
        full: the binarised re-rendered mask (ablation ``concat-full``).
        views: names of the views, in order.
    """

    center: torch.Tensor
    soft: torch.Tensor
    full: torch.Tensor
    views: tuple[str, ...]

    def as_dict(self) -> dict[str, torch.Tensor]:
        return {"center": self.center, "soft": self.soft, "full": self.full}


def mask_views(renderer: OrthographicRenderer, cloud: PointCloud | np.ndarray,
               mask: np.ndarray | torch.Tensor | MaskField, binarize_threshold: float = 0.5) -> MaskViews:
    """Render a per-point mask into the virtual views and post-process it.

    Args:
        renderer: an :class:`abm.render.OrthographicRenderer`.
        cloud: the :class:`abm.geometry.PointCloud` the mask belongs to (or an ``(N, 3)`` xyz array).
        mask: ``(N,)`` per-point values (a :class:`MaskField` uses its ``mask``).
        binarize_threshold: threshold of the ``full`` variant.

    Returns:
        :class:`MaskViews` of ``(V, H, W)`` tensors.
    """
    if isinstance(mask, MaskField):
        mask = mask.mask
    xyz = getattr(cloud, "xyz", cloud)
    rgb = getattr(cloud, "rgb", None)
    points = torch.as_tensor(np.asarray(xyz), dtype=torch.float32)
    values = torch.as_tensor(np.asarray(mask), dtype=torch.float32).reshape(-1, 1)
    if values.shape[0] != points.shape[0]:
        raise ValueError(f"mask has {values.shape[0]} values but the cloud has {points.shape[0]} points")
    colours = torch.as_tensor(np.asarray(rgb), dtype=torch.float32) if rgb is not None else torch.zeros_like(points)
    out = renderer.render(points, colours, extra=values)
    rendered = out.extra[0, :, 0]
    soft = soft_mask(rendered)
    full = binarize_mask(rendered, binarize_threshold)
    center = center_pixel_mask(full)
    return MaskViews(center=center, soft=soft, full=full, views=tuple(renderer.views))


def negative_prompts(negatives: Sequence[str]) -> list[str]:
    """Prompts for the negative phrases (same template as the target)."""
    return [clip_prompt(n) for n in negatives]
