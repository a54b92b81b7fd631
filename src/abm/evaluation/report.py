"""Figures for run reports: training curves and the virtual views a policy sees."""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path

import numpy as np


def plot_training_curves(runs: Mapping[str, str | Path], path: str | Path) -> Path:
    """Plot the total and per-head training losses of runs (label -> run folder with ``log.csv``) to a PNG,
    with the validation loss (``val_total``, dashed) beside the total when the run logged one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    heads = ("total", "translation", "rotation", "gripper")
    fig, axes = plt.subplots(1, len(heads), figsize=(4 * len(heads), 3.2))
    for label, run in runs.items():
        log = Path(run) / "log.csv"
        if not log.is_file():
            continue
        with log.open() as f:
            rows = list(csv.DictReader(f))
        steps = [int(r["step"]) for r in rows]
        for ax, head in zip(axes, heads, strict=True):
            values = [float(r[head]) if r.get(head) not in (None, "") else np.nan for r in rows]
            line = ax.plot(steps, values, label=label)[0]
        held_out = [(int(r["step"]), float(r["val_total"])) for r in rows if r.get("val_total") not in (None, "")]
        if held_out:  # the validation loss (abm train --val-data) beside the total training loss
            axes[0].plot(*zip(*held_out, strict=True), "o--", color=line.get_color(), label=f"{label} validation")
    for ax, head in zip(axes, heads, strict=True):
        ax.set_title(f"{head} loss")
        ax.set_xlabel("step")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


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
    img = img.resize((img.width * scale, img.height * scale), Image.NEAREST)
    draw = ImageDraw.Draw(img)
    for v, name in enumerate(view_names):
        draw.text((v * images.shape[-1] * scale + 3, 3), name, fill=(255, 255, 255))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)
    return path
