"""Figures for run reports: the virtual views a policy sees (the training curves: :mod:`abm.evaluation.plots`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def views_figure(images: np.ndarray, mask: np.ndarray | None, view_names: list[str], path: str | Path) -> Path:
    """Save the virtual views with the mask channel on top.

    Args:
        images: ``(V, 10, H, W)`` RVT channels of one sample (rgb first, in ``[0, 1]``).
        mask: ``(V, C, H, W)`` mask channel(s) of the sample (first channel drawn), or ``None``.
        view_names: names of the ``V`` views.
    """
    from PIL import Image, ImageDraw

    tiles = []
    for v, _ in enumerate(view_names):
        rgb = np.clip(images[v, :3].transpose(1, 2, 0), 0, 1)
        overlay = rgb.copy()
        if mask is not None:
            m = mask[v, 0] > 0
            overlay[m] = (1.0, 0.0, 1.0)
            rows, cols = np.nonzero(m)
            for r, c in zip(rows, cols, strict=True):  # enlarge single centre pixels so they show
                overlay[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3] = (1.0, 0.0, 1.0)
        tiles.append(np.concatenate([rgb, overlay], axis=0))
    img = Image.fromarray((np.concatenate(tiles, axis=1) * 255).round().astype(np.uint8))
    scale = max(1, 192 // images.shape[-1])
    img = img.resize((img.width * scale, img.height * scale), Image.Resampling.NEAREST)
    draw = ImageDraw.Draw(img)
    for v, name in enumerate(view_names):
        draw.text((v * images.shape[-1] * scale + 3, 3), name, fill=(255, 255, 255))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)
    return path
