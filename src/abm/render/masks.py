"""Post-processing of rendered mask channels into the three forms compared in the ABM paper.

* ``soft_mask``: the re-rendered mask as is, clamped to ``[0, 1]`` (ablation "concat-rerendered").
* ``binarize_mask``: 1 where the rendered mask exceeds a threshold (ablation "concat-full").
* ``center_pixel_mask``: a single 1 at the centre of the mask region (the method).

All functions work on any leading batch/view dimensions: ``mask`` is ``(..., H, W)``.
"""

from __future__ import annotations

import torch


def soft_mask(mask: torch.Tensor) -> torch.Tensor:
    """The soft re-rendered mask clamped to ``[0, 1]``; shape ``(..., H, W)``."""
    return mask.clamp(0.0, 1.0)


def binarize_mask(mask: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """``1.0`` where ``mask > threshold``, else ``0.0``; shape ``(..., H, W)``."""
    return (mask > threshold).to(mask.dtype if mask.is_floating_point() else torch.float32)


def center_pixel_mask(mask: torch.Tensor, threshold: float = 0.0) -> torch.Tensor:
    """Keep only the pixel at the centre of the region where ``mask > threshold``.

    The centre is the centroid of the region's pixels; when the centroid falls outside the region
    (a ring, two separate parts), the region pixel nearest to it is used, so the marked pixel always
    lies on the object. A mask with an empty region stays all zero.

    Args:
        mask: ``(..., H, W)`` rendered mask.
        threshold: pixels strictly above it form the region.

    Returns:
        ``(..., H, W)`` float tensor with at most one 1.0 per image.
    """
    if mask.dim() < 2:
        raise ValueError(f"mask must be (..., H, W), got shape {tuple(mask.shape)}")
    *lead, h, w = mask.shape
    region = (mask > threshold).reshape(-1, h * w)
    rows = torch.arange(h, device=mask.device).repeat_interleave(w).to(torch.float32)
    cols = torch.arange(w, device=mask.device).repeat(h).to(torch.float32)
    count = region.sum(-1, keepdim=True)
    denom = count.clamp(min=1).to(torch.float32)
    r0 = (region * rows).sum(-1, keepdim=True) / denom
    c0 = (region * cols).sum(-1, keepdim=True) / denom
    dist = (rows - r0) ** 2 + (cols - c0) ** 2
    dist = torch.where(region, dist, torch.full_like(dist, float("inf")))
    out = torch.zeros(region.shape, dtype=torch.float32, device=mask.device)
    out.scatter_(1, dist.argmin(-1, keepdim=True), 1.0)
    out = out * (count > 0)
    return out.view(*lead, h, w)
