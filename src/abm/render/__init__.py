"""Virtual views: orthographic re-rendering of point clouds and mask post-processing."""

from abm.render.masks import binarize_mask, center_pixel_mask, soft_mask
from abm.render.orthographic import VIEW_AXES, VIEW_NAMES, OrthographicRenderer, RenderedViews

__all__ = [
    "VIEW_AXES", "VIEW_NAMES", "OrthographicRenderer", "RenderedViews", "binarize_mask", "center_pixel_mask",
    "soft_mask",
]
