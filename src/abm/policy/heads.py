"""Training targets, the loss, and decoding of the model outputs into keyframe actions.

Translation: the target of each view is a Gaussian (``sigma`` pixels, default 1.5) around the target
point's projection into that view, normalised to sum to 1; the loss is the cross-entropy of the
view's pixel softmax against it. We report it minus the target's own entropy (the KL divergence;
same gradients), so a perfect prediction has loss 0. Rotation, gripper and ignore-collision are
plain cross-entropies. The total is the sum.

Decoding the 3-D point: every view's heatmap becomes a log-probability map; a candidate world point
scores the sum over views of the log-probability at its projection (bilinear). Candidates are a
coarse grid over the workspace cube scored against max-pooled maps (so a sharp peak between grid
points is not missed), then two finer local grids around the best candidate (the last at 1 px), and
the answer is the probability-weighted mean of the last grid (sub-pixel).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from abm.policy.action_coding import decode_action
from abm.policy.mvt import PolicyOutput
from abm.render import OrthographicRenderer
from abm.types import KeyframeAction


@dataclass
class LossTerms:
    """Loss terms (scalars); ``total`` is their sum. ``translation`` is the heatmap term over the workspace (the
    coarse stage's in a two-stage policy), ``zoom_translation`` the zoomed stage's (0 for one stage)."""

    total: torch.Tensor
    translation: torch.Tensor
    rotation: torch.Tensor
    gripper: torch.Tensor
    collision: torch.Tensor
    zoom_translation: torch.Tensor


def translation_targets(renderer: OrthographicRenderer, positions: torch.Tensor, sigma: float = 1.5) -> torch.Tensor:
    """Per-view Gaussian heatmap targets.

    Args:
        renderer: gives the view projection (and resolution ``H = W``).
        positions: ``(B, 3)`` world metres.
        sigma: Gaussian standard deviation in pixels.

    Returns:
        ``(B, V, H, W)`` float32, each view summing to 1.
    """
    res = renderer.resolution
    uv, _ = renderer.project(positions)  # (B, V, 2)
    grid = torch.arange(res, device=uv.device, dtype=torch.float32)
    du = (grid.view(1, 1, 1, res) - uv[..., 0, None, None]) ** 2  # (B, V, 1, W)
    dv = (grid.view(1, 1, res, 1) - uv[..., 1, None, None]) ** 2  # (B, V, H, 1)
    logits = -(du + dv) / (2.0 * sigma**2)
    return torch.softmax(logits.flatten(2), -1).view(*uv.shape[:2], res, res)


def heatmap_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """KL divergence of the views' pixel softmax from the target heatmaps, summed over views, batch mean.

    Args:
        logits: ``(B, V, H, W)`` translation logits.
        target: ``(B, V, H, W)`` from :func:`translation_targets`.
    """
    logp = torch.log_softmax(logits.float().flatten(2), -1)
    tgt = target.float().flatten(2)
    return (tgt * (torch.log(tgt.clamp_min(1e-30)) - logp)).sum(-1).sum(-1).mean()


def policy_loss(
    out: PolicyOutput,
    heat_target: torch.Tensor,
    rotation_bins: torch.Tensor,
    gripper: torch.Tensor,
    collision: torch.Tensor,
    coarse_target: torch.Tensor | None = None,
) -> LossTerms:
    """Sum of cross-entropies (batch means).

    Args:
        out: model output.
        heat_target: ``(B, V, H, W)`` from :func:`translation_targets` for ``out.heatmap`` (the zoomed views in a
            two-stage policy).
        rotation_bins: ``(B, 3)`` int64.
        gripper: ``(B,)`` int64, 1 = open.
        collision: ``(B,)`` int64, 1 = ignore collisions.
        coarse_target: two-stage policies: ``(B, V, H1, W1)`` the target of ``out.coarse_heatmap``.
    """
    b = heat_target.shape[0]
    trans = heatmap_loss(out.heatmap, heat_target)
    zoom = trans.new_zeros(())
    if out.coarse_heatmap is not None:
        if coarse_target is None:
            raise ValueError("a two-stage output needs the coarse heatmap's target (coarse_target)")
        trans, zoom = heatmap_loss(out.coarse_heatmap, coarse_target), trans
    nb = out.rotation.shape[-1]
    rot = F.cross_entropy(out.rotation.float().reshape(b * 3, nb), rotation_bins.reshape(-1), reduction="sum") / b
    grip = F.cross_entropy(out.gripper.float(), gripper)
    coll = F.cross_entropy(out.collision.float(), collision)
    return LossTerms(trans + zoom + rot + grip + coll, trans, rot, grip, coll, zoom)


def _sample(logp: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of ``logp`` ``(B, V, H, W)`` at pixel coordinates ``uv`` ``(B, M, V, 2)`` -> ``(B, M)``
    summed over views."""
    b, v, h, w = logp.shape
    norm = torch.stack([uv[..., 0] / (w - 1), uv[..., 1] / (h - 1)], -1) * 2 - 1  # pixel centres -> [-1, 1]
    grid = norm.permute(0, 2, 1, 3).reshape(b * v, -1, 1, 2)  # (B*V, M, 1, 2)
    vals = F.grid_sample(logp.reshape(b * v, 1, h, w), grid, mode="bilinear", padding_mode="border",
                         align_corners=True)
    return vals.view(b, v, -1).sum(1)


def decode_translation(
    heatmap: torch.Tensor, renderer: OrthographicRenderer, coarse_px: int = 4, refine_steps: int = 4
) -> torch.Tensor:
    """The 3-D point where the views' heatmaps agree.

    Args:
        heatmap: ``(B, V, H, W)`` logits.
        renderer: the renderer the views came from (its projection and workspace cube).
        coarse_px: coarse grid spacing in pixels.
        refine_steps: half-width (in grid steps) of each local refinement grid.

    Returns:
        ``(B, 3)`` world metres inside the workspace cube.
    """
    b = heatmap.shape[0]
    res = renderer.resolution
    logp = torch.log_softmax(heatmap.float().flatten(2), -1).view_as(heatmap).to(renderer.device)
    ws = renderer.workspace
    lo = torch.tensor(ws.lower, dtype=torch.float32, device=renderer.device)
    px = ws.size / res  # metres per pixel
    # coarse: cell centres every `coarse_px` pixels, scored on max-pooled maps
    n = max(res // coarse_px, 1)
    axis = (torch.arange(n, device=renderer.device, dtype=torch.float32) + 0.5) * (ws.size / n)
    cand = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3) + lo
    k = coarse_px + 1 if coarse_px % 2 == 0 else coarse_px
    pooled = F.max_pool2d(logp.flatten(0, 1).unsqueeze(1), k, stride=1, padding=k // 2).view_as(logp)
    uv, _ = renderer.project(cand)  # (M, V, 2)
    score = _sample(pooled, uv.unsqueeze(0).expand(b, -1, -1, -1))
    best = cand[score.argmax(-1)]  # (B, 3)
    # refinement: local grids of +-refine_steps at coarse/2 px and 1 px (argmax), then the
    # probability-weighted mean over the 1 px grid (bilinear log-maps peak at pixel centres, so an
    # argmax alone cannot resolve sub-pixel positions)
    upper = lo + ws.size
    off = torch.arange(-refine_steps, refine_steps + 1, device=renderer.device, dtype=torch.float32)
    unit = torch.stack(torch.meshgrid(off, off, off, indexing="ij"), -1).reshape(1, -1, 3)
    for step in (px * coarse_px / 2, px):
        cand_b = torch.minimum(torch.maximum(best.unsqueeze(1) + unit * step, lo), upper)  # (B, M, 3)
        uv, _ = renderer.project(cand_b)
        score = _sample(logp, uv)
        best = cand_b[torch.arange(b, device=renderer.device), score.argmax(-1)]
    weights = torch.softmax(score, -1).unsqueeze(-1)
    best = torch.minimum(torch.maximum((weights * cand_b).sum(1), lo), upper)
    return best


def decode_output(out: PolicyOutput, renderer: OrthographicRenderer,
                  zoom_renderer: OrthographicRenderer | None = None) -> list[KeyframeAction]:
    """Model output of a batch -> one :class:`KeyframeAction` per sample.

    A two-stage output (``out.zoom_center`` set) decodes its heatmap with ``zoom_renderer`` (the zoom cube
    centred at the origin) and adds the zoom centre; ``renderer`` is then unused.
    """
    if out.zoom_center is None:
        position = decode_translation(out.heatmap.detach(), renderer)
    else:
        if zoom_renderer is None:
            raise ValueError("a two-stage output needs the zoomed stage's renderer (zoom_renderer) to decode")
        position = decode_translation(out.heatmap.detach(), zoom_renderer) + out.zoom_center.to(zoom_renderer.device)
    pos = position.cpu().numpy()
    rot = out.rotation.detach().argmax(-1).cpu().numpy()
    grip = out.gripper.detach().argmax(-1).cpu().numpy()
    coll = out.collision.detach().argmax(-1).cpu().numpy()
    nb = out.rotation.shape[-1]
    return [decode_action(pos[i], rot[i], int(grip[i]), int(coll[i]), nb) for i in range(pos.shape[0])]


def logits_from_targets(
    positions: torch.Tensor,
    rotation_bins: torch.Tensor,
    gripper: Sequence[int] | torch.Tensor,
    collision: Sequence[int] | torch.Tensor,
    renderer: OrthographicRenderer,
    sigma: float = 1.5,
    num_bins: int = 72,
) -> PolicyOutput:
    """An ideal :class:`PolicyOutput` for given targets (log of the target heatmaps, one-hot logits):
    the inverse of decoding, used to test the encode/decode round trip through the heads."""
    heat = torch.log(translation_targets(renderer, positions, sigma).clamp_min(1e-30))
    rot = F.one_hot(rotation_bins, num_bins).float() * 20.0
    grip = F.one_hot(torch.as_tensor(gripper), 2).float() * 20.0
    coll = F.one_hot(torch.as_tensor(collision), 2).float() * 20.0
    return PolicyOutput(heat, rot, grip, coll)
