"""Virtual views: orthographic re-rendering of point clouds and mask post-processing."""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.render.masks import binarize_mask, center_pixel_mask, soft_mask
    from abm.render.orthographic import VIEW_AXES, VIEW_NAMES, OrthographicRenderer, RenderedViews

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "VIEW_AXES", "VIEW_NAMES", "OrthographicRenderer", "RenderedViews", "binarize_mask", "center_pixel_mask",
    "soft_mask",
]
