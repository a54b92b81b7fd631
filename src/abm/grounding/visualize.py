"""PNG helpers for inspecting grounding results (PIL only, no plotting library).

Images are ``uint8`` ``(H, W, 3)`` arrays; heatmaps are float arrays in ``[0, 1]``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

# Anchor colours of a perceptually ordered blue -> cyan -> green -> yellow -> red colormap.
_ANCHORS = np.array([
    [0.19, 0.07, 0.23], [0.16, 0.47, 0.93], [0.11, 0.82, 0.77], [0.49, 0.98, 0.31],
    [0.95, 0.82, 0.14], [0.94, 0.36, 0.07], [0.48, 0.02, 0.01],
])


def colormap(values: np.ndarray) -> NDArray[np.uint8]:
    """Values ``(...)`` in ``[0, 1]`` -> colours ``(..., 3)`` uint8 (piecewise-linear, blue = low, red = high)."""
    v = np.clip(np.nan_to_num(np.asarray(values, np.float64)), 0.0, 1.0) * (len(_ANCHORS) - 1)
    lo = np.minimum(np.floor(v).astype(int), len(_ANCHORS) - 2)
    frac = (v - lo)[..., None]
    rgb = _ANCHORS[lo] * (1 - frac) + _ANCHORS[lo + 1] * frac
    colours: NDArray[np.uint8] = (rgb * 255).round().astype(np.uint8)
    return colours


def blend(base: np.ndarray, overlay: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """``base * (1 - alpha) + overlay * alpha`` for uint8 images; ``alpha`` scalar or ``(H, W)``."""
    a = np.asarray(alpha, np.float64)
    if a.ndim == 2:
        a = a[..., None]
    out = base.astype(np.float64) * (1 - a) + overlay.astype(np.float64) * a
    return np.clip(out, 0, 255).round().astype(np.uint8)


def upscale(image: np.ndarray, factor: int) -> np.ndarray:
    """Nearest-neighbour enlargement by an integer factor (keeps pixels crisp)."""
    return np.repeat(np.repeat(image, factor, axis=0), factor, axis=1) if factor > 1 else image


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in ``[0, 1]`` -> uint8."""
    return (np.clip(np.asarray(image, np.float64), 0.0, 1.0) * 255).round().astype(np.uint8)


def gray(values: np.ndarray) -> np.ndarray:
    """``(H, W)`` values in ``[0, 1]`` -> ``(H, W, 3)`` uint8 grey image."""
    return np.repeat(to_uint8(values)[..., None], 3, axis=-1)


def mark_pixels(image: np.ndarray, pixels: Sequence[tuple[int, int]], radius: int = 5,
                color: tuple[int, int, int] = (255, 0, 255)) -> np.ndarray:
    """Draw a ring and a centre dot at every ``(row, col)`` of ``pixels``."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    for r, c in pixels:
        draw.ellipse([c - radius, r - radius, c + radius, r + radius], outline=color, width=2)
        draw.rectangle([c - 1, r - 1, c + 1, r + 1], fill=color)
    return np.asarray(img)


def hstack(images: Sequence[np.ndarray], gap: int = 4) -> np.ndarray:
    """Place images side by side on a white background (tops aligned)."""
    h = max(i.shape[0] for i in images)
    w = sum(i.shape[1] for i in images) + gap * (len(images) - 1)
    out = np.full((h, w, 3), 255, np.uint8)
    x = 0
    for img in images:
        out[: img.shape[0], x: x + img.shape[1]] = img
        x += img.shape[1] + gap
    return out


def vstack(images: Sequence[np.ndarray], gap: int = 4) -> np.ndarray:
    """Stack images vertically on a white background (left aligned)."""
    w = max(i.shape[1] for i in images)
    h = sum(i.shape[0] for i in images) + gap * (len(images) - 1)
    out = np.full((h, w, 3), 255, np.uint8)
    y = 0
    for img in images:
        out[y: y + img.shape[0], : img.shape[1]] = img
        y += img.shape[0] + gap
    return out


def label(image: np.ndarray, text: str) -> np.ndarray:
    """Add a one-line caption strip above an image."""
    from PIL import Image, ImageDraw

    strip = Image.new("RGB", (image.shape[1], 14), (255, 255, 255))
    ImageDraw.Draw(strip).text((2, 1), text, fill=(0, 0, 0))
    return np.concatenate([np.asarray(strip), image], axis=0)


MASK_TINT = np.array([0, 220, 255], np.uint8)  # cyan: the target's visible pixels
MARK_COLOR = (255, 0, 200)  # magenta: the pixels abm's mask channel marks
MAX_MARKS = 16


def overlay_views(rgb: np.ndarray, target: np.ndarray | None = None, heatmaps: np.ndarray | None = None,
                  marks: np.ndarray | None = None) -> list[np.ndarray]:
    """Virtual views as pictures ``(R, R, 3)`` uint8.

    Args:
        rgb: ``(V, R, R, 3)`` rendered colour in ``[0, 1]``.
        target: ``(V, R, R)``, the target's visible pixels (> 0.5), tinted cyan.
        heatmaps: ``(V, R, R)`` predicted translation distributions, each normalised to its maximum and
            blended in with the jet colour map (opacity grows with the square root of the value).
        marks: ``(V, R, R)``, pixels the mask channel marks (> 0.5; abm marks the target's centre), drawn
            as magenta rings (when there are at most ``MAX_MARKS`` of them).
    """
    out = []
    for v in range(rgb.shape[0]):
        img = (np.clip(rgb[v], 0, 1) * 255).astype(np.uint8)
        if target is not None:
            img = blend(img, np.broadcast_to(MASK_TINT, img.shape), 0.55 * (target[v] > 0.5)[..., None])
        if heatmaps is not None:
            h = heatmaps[v] / max(float(heatmaps[v].max()), 1e-12)
            img = blend(img, colormap(h), (0.85 * np.sqrt(h))[..., None])
        if marks is not None:
            rows, cols = np.nonzero(marks[v] > 0.5)
            if 0 < len(rows) <= MAX_MARKS:  # a full mask (the ablations' channel) is already the cyan tint
                img = mark_pixels(img, list(zip(rows.tolist(), cols.tolist(), strict=True)), radius=2,
                                  color=MARK_COLOR)
        out.append(np.ascontiguousarray(img))
    return out
