"""Virtual views: orthographic re-rendering of point clouds and mask post-processing."""

from abm.lazy import lazy_exports

# imported on first use (abm.lazy), so importing the package (every `abm` command does) stays light
__getattr__, __dir__ = lazy_exports(__name__, {
    "abm.render.masks": ("binarize_mask", "center_pixel_mask", "soft_mask",),
    "abm.render.orthographic": ("VIEW_AXES", "VIEW_NAMES", "OrthographicRenderer", "RenderedViews",),
})

__all__ = [
    "VIEW_AXES", "VIEW_NAMES", "OrthographicRenderer", "RenderedViews", "binarize_mask", "center_pixel_mask",
    "soft_mask",
]
