"""Batched orthographic point renderer for the virtual views (torch; same code on CPU and CUDA).

The renderer re-renders a world-frame point cloud into ``V`` orthographic views of the workspace cube
(see docs/conventions.md for the view axes). Visibility is a z-buffer: in every pixel the point
nearest to the view wins, found with one ``scatter_reduce(amin)`` over packed ``(depth, index)``
keys, so there is no Python loop over points or pixels. Every per-point channel (colour, world
xyz, masks, features) is then gathered from the winning point, so all channels share the same
visibility.

Pixel convention: a view is ``resolution x resolution`` pixels covering one cube face exactly; the
centre of pixel ``(row, col)`` is at continuous coordinates ``(u, v) = (col, row)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from abm.geometry.workspace import Workspace

VIEW_NAMES: tuple[str, ...] = ("front", "back", "left", "right", "top")

# Rows: image right, image down, viewing direction (forward) of each view, in world axes.
VIEW_AXES: dict[str, tuple[tuple[float, float, float], ...]] = {
    "front": ((0, 1, 0), (0, 0, -1), (-1, 0, 0)),
    "back": ((0, -1, 0), (0, 0, -1), (1, 0, 0)),
    "left": ((-1, 0, 0), (0, 0, -1), (0, -1, 0)),
    "right": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "top": ((0, -1, 0), (-1, 0, 0), (0, 0, -1)),
}

_DEPTH_LEVELS = 1 << 22  # depth quantisation of the z-buffer key: 0.24 um for a 1 m cube


@dataclass
class RenderedViews:
    """Output of :meth:`OrthographicRenderer.render` (``B`` batch, ``V`` views, ``H = W`` resolution).

    Attributes:
        rgb: ``(B, V, 3, H, W)`` colour of the visible point (background 0).
        depth: ``(B, V, 1, H, W)`` metres from the view's near cube face to the visible point;
            background = the cube edge length (the far face).
        xyz: ``(B, V, 3, H, W)`` world coordinates (m) of the visible point (background 0).
        extra: ``(B, V, C, H, W)`` the extra per-point channels (masks, features), background 0;
            ``C = 0`` when none were given.
        occupied: ``(B, V, H, W)`` bool, True where a point is visible.
        pixel_loc: ``(V, 3, H, W)`` RVT's pixel-location channels: the view index scaled to
            ``[-1, 1]``, then the row and column scaled to ``[-1, 1]``.
    """

    rgb: torch.Tensor
    depth: torch.Tensor
    xyz: torch.Tensor
    extra: torch.Tensor
    occupied: torch.Tensor
    pixel_loc: torch.Tensor

    def rvt_channels(self) -> torch.Tensor:
        """``(B, V, 10, H, W)``: rgb, depth, xyz and pixel location, the RVT input layout."""
        loc = self.pixel_loc.unsqueeze(0).expand(self.rgb.shape[0], -1, -1, -1, -1)
        return torch.cat([self.rgb, self.depth, self.xyz, loc], dim=2)


class OrthographicRenderer:
    """Renders point clouds into orthographic virtual views of a workspace cube.

    Args:
        workspace: the cube the views cover.
        resolution: pixels per side of every view.
        views: names of the views, a subset of :data:`VIEW_NAMES`, in output order.
        splat_radius: each point also covers the pixels within this many pixels (a square of side
            ``2 r + 1``), which closes holes in sparse clouds; 0 = one pixel per point.
        device: where the projection matrices live; inputs are moved there.
    """

    def __init__(
        self,
        workspace: Workspace | None = None,
        resolution: int = 220,
        views: Sequence[str] = VIEW_NAMES,
        splat_radius: int = 0,
        device: str | torch.device = "cpu",
    ) -> None:
        unknown = [v for v in views if v not in VIEW_AXES]
        if unknown or not views:
            raise ValueError(f"unknown views {unknown}; choose from {list(VIEW_AXES)}")
        if resolution < 1:
            raise ValueError(f"resolution must be positive, got {resolution}")
        if splat_radius < 0:
            raise ValueError(f"splat_radius must be >= 0, got {splat_radius}")
        self.workspace = workspace or Workspace()
        self.resolution = int(resolution)
        self.views = tuple(views)
        self.splat_radius = int(splat_radius)
        self.device = torch.device(device)
        self.axes = torch.tensor([VIEW_AXES[v] for v in self.views], dtype=torch.float32, device=self.device)
        # Every view axis is a signed world axis, so a point's camera coordinates are its world coordinates
        # relative to the centre, permuted and negated (exactly what the projection's products with 0 and +-1
        # give). _signed[v, j] indexes the row of [rel; -rel] (6 rows: +x, +y, +z, -x, -y, -z) holding camera
        # axis j (right, down, forward) of view v.
        axes = self.axes.cpu()
        if not bool(((axes.abs() == 1).sum(-1) == 1).all()) or not bool((axes.abs().sum(-1) == 1).all()):
            raise ValueError("every view axis must be a signed world axis")
        self._signed = (axes.abs().argmax(-1) + 3 * (axes.sum(-1) < 0)).to(self.device)  # (V, 3) int64
        # the rows of the 6 signed coordinates some view's image axes use, and where each view's u and v are in them
        used = sorted(set(self._signed[:, :2].flatten().tolist()))
        self._uv_rows = torch.tensor(used, device=self.device)
        self._uv_index = torch.tensor([[used.index(int(i)) for i in row] for row in self._signed[:, :2].tolist()],
                                      device=self.device)  # (V, 2)
        self.center = torch.tensor(self.workspace.center, dtype=torch.float32, device=self.device)
        self.half = self.workspace.half
        self._lower = self.center - self.half
        self._upper = self.center + self.half
        self._pixel_loc: torch.Tensor | None = None

    @property
    def num_views(self) -> int:
        return len(self.views)

    def to(self, device: str | torch.device) -> OrthographicRenderer:
        """The same renderer with its tensors on ``device``."""
        return OrthographicRenderer(self.workspace, self.resolution, self.views, self.splat_radius, device)

    # ------------------------------------------------------------------ projection
    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points ``(..., 3)`` -> pixel coordinates ``(..., V, 2)`` as ``(u, v)`` = (col, row)
        (integer values are pixel centres) and depth ``(..., V)`` in metres from each view's near face."""
        rel = points.to(self.device, torch.float32) - self.center
        cam = torch.einsum("...k,vjk->...vj", rel, self.axes)
        scale = self.resolution / 2.0
        uv = (cam[..., :2] / self.half + 1.0) * scale - 0.5
        return uv, cam[..., 2] + self.half

    def unproject(self, pixels: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`project`: pixels ``(..., V, 2)`` and depth ``(..., V)`` -> world ``(..., V, 3)``."""
        pixels = pixels.to(self.device, torch.float32)
        depth = depth.to(self.device, torch.float32)
        ab = (pixels + 0.5) / (self.resolution / 2.0) - 1.0
        cam = torch.cat([ab * self.half, (depth - self.half).unsqueeze(-1)], dim=-1)
        return torch.einsum("...vj,vjk->...vk", cam, self.axes) + self.center

    def pixel_loc(self) -> torch.Tensor:
        """``(V, 3, H, W)`` RVT pixel-location channels (view index, row, column; each in ``[-1, 1]``)."""
        if self._pixel_loc is None:
            v, r = self.num_views, self.resolution
            lin = torch.linspace(-1.0, 1.0, r, device=self.device)
            view = torch.linspace(-1.0, 1.0, v, device=self.device) if v > 1 else torch.zeros(1, device=self.device)
            self._pixel_loc = torch.stack(
                [view.view(v, 1, 1).expand(v, r, r), lin.view(1, r, 1).expand(v, r, r),
                 lin.view(1, 1, r).expand(v, r, r)], dim=1
            ).contiguous()
        return self._pixel_loc

    # ------------------------------------------------------------------ rendering
    def render(
        self,
        points: torch.Tensor,
        rgb: torch.Tensor,
        extra: torch.Tensor | None = None,
        valid: torch.Tensor | None = None,
    ) -> RenderedViews:
        """Render point clouds into the virtual views.

        Args:
            points: ``(B, N, 3)`` or ``(N, 3)`` world coordinates in metres. Points outside the
                workspace cube are ignored.
            rgb: ``(B, N, 3)`` or ``(N, 3)`` colours (any range; ``[0, 1]`` by convention).
            extra: optional ``(B, N, C)`` or ``(N, C)`` further channels rendered with the same visibility.
            valid: optional ``(B, N)`` or ``(N,)`` bool; False entries (e.g. padding) are ignored.

        Returns:
            :class:`RenderedViews` with a batch dimension (``B = 1`` for unbatched input).
        """
        points, rgb, extra, valid = self._check_inputs(points, rgb, extra, valid)
        b, n, _ = points.shape
        v, res = self.num_views, self.resolution

        # Only the points inside the cube take part: gather them once as a flat list of M (sample, point) pairs,
        # so no per-view work is spent on the others. Per-point arrays are view-major ((V, M): contiguous along
        # the points, so every elementwise op runs vectorised), and each float op is project()'s, value for
        # value: the camera coordinates are signed world coordinates (see __init__), the image coordinates are
        # computed once per signed world axis that some view's image axes use (4 + 2 of the 10 for the 5 views)
        # and picked per view. The integer pixel index and z-buffer key are exact in any order.
        inside = valid & (points >= self._lower).all(-1) & (points <= self._upper).all(-1)
        bi, ni = inside.nonzero(as_tuple=True)  # (M,), (M,)
        rel = (points.view(b * n, 3).index_select(0, bi * n + ni) - self.center).t()  # (3, M)
        signed = torch.cat([rel, -rel])  # (6, M): +x, +y, +z, -x, -y, -z
        img = signed.index_select(0, self._uv_rows).div_(self.half).add_(1.0).mul_(res / 2.0).sub_(0.5)  # (U, M)
        pix_axes = img.add_(0.5).floor_().int().clamp_(0, res - 1)  # (U, M)
        cols = pix_axes.index_select(0, self._uv_index[:, 0])  # (V, M)
        rows = pix_axes.index_select(0, self._uv_index[:, 1])
        depth = signed.index_select(0, self._signed[:, 2]).add_(self.half)  # (V, M)
        # pixel indices in int32 (half the memory traffic of int64; < 2^31 for any batch that fits in memory),
        # the z-buffer key (depth level, point index) and the flat pixel index in int64
        key = depth.clamp_(0.0, 2 * self.half).div_(2 * self.half).mul_(_DEPTH_LEVELS - 1).long().mul_(n).add_(ni)
        view_base = torch.arange(v, device=self.device, dtype=torch.int32).unsqueeze(1) * (res * res)  # (V, 1)
        base = view_base + bi.int() * (v * res * res)  # (V, M): the first pixel of the point's sample and view
        sentinel = torch.iinfo(torch.int64).max
        if self.splat_radius:
            r = self.splat_radius
            offsets = torch.arange(-r, r + 1, device=self.device)
            dv, du = torch.meshgrid(offsets, offsets, indexing="ij")
            cols = cols.unsqueeze(-1) + du.reshape(-1)  # (V, M, K)
            rows = rows.unsqueeze(-1) + dv.reshape(-1)
            keep = (cols >= 0) & (cols < res) & (rows >= 0) & (rows < res)
            lin = (base.unsqueeze(-1) + torch.add(cols.clamp(0, res - 1), rows.clamp(0, res - 1), alpha=res)).long()
            # Splats falling off the view get the sentinel key, which never wins the minimum.
            key = torch.where(keep, key.unsqueeze(-1), sentinel)
        else:
            lin = base.add_(torch.add(cols, rows, alpha=res)).long()

        zbuf = torch.full((b * v * res * res,), sentinel, dtype=torch.int64, device=self.device)
        zbuf.scatter_reduce_(0, lin.reshape(-1), key.reshape(-1), reduce="amin", include_self=True)
        occupied = zbuf != sentinel
        # Row b * n + i of a channel is point i of batch b.
        pixel_batch = torch.arange(b, device=self.device).repeat_interleave(v * res * res)
        source = torch.where(occupied, pixel_batch * n + zbuf % n, 0)
        channels = [rgb, points] + ([extra] if extra is not None else [])
        gathered = torch.cat([c.reshape(b * n, -1).index_select(0, source) for c in channels], dim=-1)
        gathered.masked_fill_(~occupied.unsqueeze(1), 0.0)  # background 0
        out = gathered.view(b, v, res, res, -1).permute(0, 1, 4, 2, 3)
        occupied = occupied.view(b, v, res, res)

        xyz = out[:, :, 3:6]
        depth_img = torch.einsum("bvkhw,vk->bvhw", xyz - self.center.view(1, 1, 3, 1, 1), self.axes[:, 2]) + self.half
        depth_img = torch.where(occupied, depth_img, torch.full_like(depth_img, 2 * self.half)).unsqueeze(2)
        return RenderedViews(
            rgb=out[:, :, 0:3], depth=depth_img, xyz=xyz, extra=out[:, :, 6:], occupied=occupied,
            pixel_loc=self.pixel_loc(),
        )

    def _check_inputs(
        self,
        points: torch.Tensor,
        rgb: torch.Tensor,
        extra: torch.Tensor | None,
        valid: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """Validate shapes, add the batch dimension and move everything to the renderer's device."""
        if not isinstance(points, torch.Tensor) or points.shape[-1:] != (3,) or points.dim() not in (2, 3):
            shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
            raise ValueError(f"points must be a (B, N, 3) or (N, 3) tensor, got {shape}")
        unbatched = points.dim() == 2
        points = (points.unsqueeze(0) if unbatched else points).to(self.device, torch.float32)
        b, n, _ = points.shape
        if n == 0:
            raise ValueError("cannot render an empty point cloud (N = 0)")

        def batch(name: str, t: torch.Tensor, width: int | None) -> torch.Tensor:
            t = t.unsqueeze(0) if unbatched else t
            if t.dim() != 3 or t.shape[:2] != (b, n) or (width is not None and t.shape[2] != width):
                want = f"({b}, {n}, {width if width is not None else 'C'})"
                raise ValueError(f"{name} must have shape {want} to match points, got {tuple(t.shape)}")
            return t.to(self.device, torch.float32)

        rgb = batch("rgb", rgb, 3)
        extra = batch("extra", extra, None) if extra is not None else None
        if valid is None:
            valid = torch.ones(b, n, dtype=torch.bool, device=self.device)
        else:
            valid = valid.unsqueeze(0) if unbatched else valid
            if valid.shape != (b, n):
                raise ValueError(f"valid must have shape ({b}, {n}) to match points, got {tuple(valid.shape)}")
            valid = valid.to(self.device, torch.bool)
        return points, rgb, extra, valid
