"""The RVT-style multi-view transformer shared by every variant (abm, rvt, ifd and the ablations).

Data flow for a batch of ``B`` samples with ``V`` virtual views of ``H x W`` pixels:

1. **Stem**: a 3x3 conv over each view's 10 RVT channels (+1 mask channel for ``stack``) at full
   resolution -> ``C`` stem channels.
2. **Conditioning after the stem**: the variant's mask channel (``abm``: centre pixel,
   ``concat-*``: soft / binary mask) and/or the re-rendered CLIP features (``ifd``, projected per
   point to ``C`` channels, then gathered into the views through the renderer's visible-point index)
   are concatenated with the stem features and fused by a 1x1 conv.
3. **Patchify**: a ``p x p`` stride-``p`` conv (``C`` channels) and a linear map -> ``(H/p) x (W/p)``
   tokens of width ``d`` per view, plus a
   learned position embedding per view and token and the projected proprioception on every token.
4. **Transformer**: ``layers_within`` pre-norm blocks over each view's tokens separately, then
   ``layers_joint`` blocks over all views' tokens together with the ``L`` projected language tokens.
   Attention uses :func:`torch.nn.functional.scaled_dot_product_attention`.
5. **Heads**: tokens are up-sampled by pixel shuffle back to ``H x W``, added to a 1x1 projection of
   the fused stem features (skip connection; after conditioning, so a mask pixel can reach the heatmap
   at full resolution without passing through the patch tokens) and decoded by two small convs into
   one translation logit per pixel and view. A global feature per view (max-pooled tokens and tokens
   pooled with the heatmap: the ground-truth one in training, the predicted one at inference; with
   ``local_rotation_features`` also the full-resolution decoder features pooled with it pixel by pixel; with
   ``rotation_crop`` also a small CNN's reading of a crop of the stem features around its most likely pixel) goes
   through an MLP to the rotation logits (3 axes x ``rotation_bins``), gripper-open and
   ignore-collision logits (2 each).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from abm.policy.config import PolicyConfig

CHANNELS_LAST = torch.channels_last


def _pointwise(conv: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """A 1x1 convolution applied to a channels-last map ``(N, H, W, C_in)`` as one matrix product over the
    channels -> ``(N, H, W, C_out)`` (the same function as ``conv`` on the ``(N, C, H, W)`` view)."""
    assert isinstance(conv, nn.Conv2d) and conv.kernel_size == (1, 1)
    return F.linear(x, conv.weight.reshape(conv.out_channels, conv.in_channels), conv.bias)


@dataclass
class PolicyOutput:
    """Raw model outputs (logits).

    Attributes:
        heatmap: ``(B, V, H, W)`` translation logits per view (softmax over each view's pixels).
        rotation: ``(B, 3, bins)`` logits of the extrinsic xyz Euler-angle bins.
        gripper: ``(B, 2)`` logits, index 1 = open.
        collision: ``(B, 2)`` logits, index 1 = ignore collisions.
        coarse_heatmap: two-stage policies: ``(B, V, H1, W1)`` the coarse stage's logits over the workspace
            (``heatmap`` is then the zoomed stage's, over the zoom cube); ``None`` for one stage.
        zoom_center: two-stage policies: ``(B, 3)`` world metres, the centre of the zoom cube; ``None`` otherwise.
    """

    heatmap: torch.Tensor
    rotation: torch.Tensor
    gripper: torch.Tensor
    collision: torch.Tensor
    coarse_heatmap: torch.Tensor | None = None
    zoom_center: torch.Tensor | None = None


class Attention(nn.Module):
    """Multi-head self-attention through ``scaled_dot_product_attention``."""

    def __init__(self, width: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(width, 3 * width)
        self.proj = nn.Linear(width, width)
        self.dropout = dropout

    def forward(self, x: torch.Tensor, queries: int | None = None) -> torch.Tensor:
        """``x`` ``(B, T, d)`` -> ``(B, T, d)``; with ``queries`` only the outputs of the first ``queries`` tokens
        ``(B, queries, d)`` (every token is still a key and a value; the other tokens' queries are not computed)."""
        b, t, d = x.shape
        dropout = self.dropout if self.training else 0.0
        if queries is None or queries == t:
            q, k, v = self.qkv(x).view(b, t, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
            out = F.scaled_dot_product_attention(q, k, v, dropout_p=dropout)
            projected: torch.Tensor = self.proj(out.transpose(1, 2).reshape(b, t, d))
            return projected
        weight, bias = self.qkv.weight, self.qkv.bias  # rows: the query's d, the key's d, the value's d
        q = F.linear(x[:, :queries], weight[:d], bias[:d]).view(b, queries, self.heads, d // self.heads)
        k, v = F.linear(x, weight[d:], bias[d:]).view(b, t, 2, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q.transpose(1, 2), k, v, dropout_p=dropout)
        projected = self.proj(out.transpose(1, 2).reshape(b, queries, d))
        return projected


class Block(nn.Module):
    """Pre-norm transformer block: ``x + attn(ln(x))``, then ``x + mlp(ln(x))``."""

    def __init__(self, width: int, heads: int, mlp_ratio: float, dropout: float) -> None:
        super().__init__()
        hidden = int(width * mlp_ratio)
        self.norm1 = nn.LayerNorm(width)
        self.attn = Attention(width, heads, dropout)
        self.norm2 = nn.LayerNorm(width)
        self.mlp = nn.Sequential(nn.Linear(width, hidden), nn.GELU(), nn.Dropout(dropout), nn.Linear(hidden, width))

    def forward(self, x: torch.Tensor, queries: int | None = None) -> torch.Tensor:
        """``x`` ``(B, T, d)`` -> ``(B, T, d)``, or with ``queries`` the outputs of the first ``queries`` tokens only
        (the same values: a token's output depends on the others only through their keys and values)."""
        h = self.norm1(x)
        if queries is not None:
            x = x[:, :queries]
        x = x + self.attn(h, queries)
        out: torch.Tensor = x + self.mlp(self.norm2(x))
        return out


def _crop_at_mode(features: torch.Tensor, prob: torch.Tensor, size: int) -> torch.Tensor:
    """Square crops of channels-last maps centred on each map's most likely pixel, zero outside the map.

    Args:
        features: ``(N, H, W, C)`` channels-last feature maps.
        prob: ``(N, H, W)`` a distribution per map (only its argmax is used; no gradient flows through it).
        size: crop side ``K`` (pixels, even): the crop holds rows and columns ``[centre - K/2, centre + K/2)``.

    Returns:
        ``(N, C, K, K)`` crops (gradients flow to ``features``).
    """
    n, h, w, _ = features.shape
    mode = prob.detach().flatten(1).argmax(1)
    half = size // 2
    offsets = torch.arange(size, device=features.device)
    rows = (mode // w).view(n, 1, 1) + offsets.view(1, size, 1)  # in the padded map: centre - K/2 + half
    cols = (mode % w).view(n, 1, 1) + offsets.view(1, 1, size)
    padded = F.pad(features, (0, 0, half, half, half, half))
    crops = padded[torch.arange(n, device=features.device).view(n, 1, 1), rows, cols]  # (N, K, K, C)
    return crops.permute(0, 3, 1, 2)


class MultiViewTransformer(nn.Module):
    """One model class for all variants; the variant in ``config`` decides which inputs it takes.

    Args:
        config: variant and sizes.
        rotation_head: build the global head (rotation, gripper, collision). The coarse stage of a two-stage
            policy predicts only the translation heatmap: its outputs then hold zero-width rotation ``(B, 3, 0)``,
            gripper ``(B, 0)`` and collision ``(B, 0)`` logits.
    """

    def __init__(self, config: PolicyConfig, rotation_head: bool = True) -> None:
        super().__init__()
        self.config = config
        spec = config.spec
        c, d, p, v = config.stem_channels, config.width, config.patch_size, config.num_views
        masks = config.mask_channels  # the target's, and with destination_mask the destination's
        in_ch = config.image_channels + (masks if spec.mask_stage == "input" else 0)
        self.stem = nn.Sequential(nn.Conv2d(in_ch, c, 3, padding=1), nn.GELU())
        extra = (masks if spec.mask_stage == "stem" else 0) + (c if spec.clip_features else 0)
        self.ifd_proj = nn.Linear(config.ifd_feature_dim, c) if spec.clip_features else None
        self.fuse = nn.Sequential(nn.Conv2d(c + extra, c, 1), nn.GELU()) if extra else nn.Identity()
        self.patchify = nn.Conv2d(c, c, p, stride=p)
        self.embed = nn.Linear(c, d)
        tokens = config.grid**2
        self.view_pos = nn.Parameter(torch.randn(v, tokens, d) * 0.02)
        self.proprio = nn.Linear(config.proprio_size, d)
        self.lang_proj = nn.Linear(config.lang_dim, d)
        self.lang_pos = nn.Parameter(torch.randn(config.lang_tokens, d) * 0.02)
        self.within = nn.ModuleList(
            Block(d, config.heads, config.mlp_ratio, config.dropout) for _ in range(config.layers_within)
        )
        self.joint = nn.ModuleList(
            Block(d, config.heads, config.mlp_ratio, config.dropout) for _ in range(config.layers_joint)
        )
        self.norm = nn.LayerNorm(d)
        dc = config.decoder_channels
        self.up = nn.Linear(d, dc * p * p)
        self.skip = nn.Conv2d(c, dc, 1)
        self.decode = nn.Sequential(nn.GELU(), nn.Conv2d(dc, dc, 3, padding=1), nn.GELU(), nn.Conv2d(dc, 1, 1))
        out = 3 * config.rotation_bins + 2 + 2
        crop = config.rotation_crop
        self.crop_net = (nn.Sequential(  # (B*V, C, K, K) -> (B*V, d): the object's outline at full resolution
            nn.Conv2d(c, 32, 3, padding=1), nn.GELU(), nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.GELU(),
            nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.GELU(), nn.Flatten(), nn.Linear(64 * (crop // 4) ** 2, d),
        ) if crop and rotation_head else None)
        per_view = 2 * d + (dc if config.local_rotation_features else 0) + (d if self.crop_net is not None else 0)
        self.global_head = (nn.Sequential(nn.Linear(per_view * v, d), nn.GELU(), nn.Linear(d, out))
                            if rotation_head else None)
        for module in (self.stem[0], self.decode[1]):  # the 3x3 convolutions' weights in their inputs' layout
            assert isinstance(module, nn.Conv2d)
            module.weight.data = module.weight.data.contiguous(memory_format=CHANNELS_LAST)

    # ------------------------------------------------------------------ input checks
    def _check(
        self,
        images: torch.Tensor,
        proprio: torch.Tensor,
        lang: torch.Tensor,
        mask: torch.Tensor | None,
        ifd_features: torch.Tensor | None,
        ifd_index: torch.Tensor | None,
    ) -> None:
        cfg, spec = self.config, self.config.spec
        want = (cfg.num_views, cfg.image_channels, cfg.resolution, cfg.resolution)
        if images.dim() != 5 or tuple(images.shape[1:]) != want:
            raise ValueError(f"images must be (B, {', '.join(map(str, want))}), got {tuple(images.shape)}")
        b = images.shape[0]
        if spec.uses_mask:
            m = cfg.mask_channels
            if mask is None:
                raise ValueError(
                    f"variant {spec.name!r} needs a mask input of shape (B, {cfg.num_views}, {m}, "
                    f"{cfg.resolution}, {cfg.resolution}) ({spec.mask} mask from the grounder); got none"
                )
            if tuple(mask.shape) != (b, cfg.num_views, m, cfg.resolution, cfg.resolution):
                raise ValueError(
                    f"mask must be ({b}, {cfg.num_views}, {m}, {cfg.resolution}, {cfg.resolution}) for variant "
                    f"{spec.name!r}{' with destination_mask' if cfg.destination_mask else ''}, "
                    f"got {tuple(mask.shape)}"
                )
        elif mask is not None:
            raise ValueError(f"variant {spec.name!r} takes no mask input, but one was given")
        if spec.clip_features:
            if ifd_features is None or ifd_index is None:
                raise ValueError(
                    f"variant {spec.name!r} needs ifd_features (B, M, {cfg.ifd_feature_dim}) and ifd_index "
                    f"(B, V, H, W) (re-rendered CLIP point features); got none"
                )
            if ifd_features.dim() != 3 or ifd_features.shape[0] != b or ifd_features.shape[2] != cfg.ifd_feature_dim:
                raise ValueError(
                    f"ifd_features must be ({b}, M, {cfg.ifd_feature_dim}), got {tuple(ifd_features.shape)}"
                )
            if tuple(ifd_index.shape) != (b, cfg.num_views, cfg.resolution, cfg.resolution):
                raise ValueError(f"ifd_index must be ({b}, {cfg.num_views}, H, W), got {tuple(ifd_index.shape)}")
        elif ifd_features is not None:
            raise ValueError(f"variant {spec.name!r} takes no CLIP features, but ifd_features were given")
        if tuple(proprio.shape) != (b, cfg.proprio_size):
            raise ValueError(f"proprio must be ({b}, {cfg.proprio_size}), got {tuple(proprio.shape)}")
        if tuple(lang.shape) != (b, cfg.lang_tokens, cfg.lang_dim):
            raise ValueError(
                f"lang must be ({b}, {cfg.lang_tokens}, {cfg.lang_dim}) language token embeddings, "
                f"got {tuple(lang.shape)}"
            )

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        images: torch.Tensor,
        proprio: torch.Tensor,
        lang: torch.Tensor,
        mask: torch.Tensor | None = None,
        ifd_features: torch.Tensor | None = None,
        ifd_index: torch.Tensor | None = None,
        pool_weights: torch.Tensor | None = None,
    ) -> PolicyOutput:
        """Predict a keyframe.

        Args:
            images: ``(B, V, 10, H, W)`` rendered RVT channels (rgb, depth, xyz, pixel location).
            proprio: ``(B, proprio_size)`` gripper open state and position (cube coordinates), and with
                ``progress_input`` the progress (:func:`abm.policy.keyframe_policy.proprioception`).
            lang: ``(B, L, lang_dim)`` language token embeddings.
            mask: ``(B, V, M, H, W)`` the variant's mask channels (mask variants only): the target's, and with
                ``destination_mask`` the destination's (``M = config.mask_channels``).
            ifd_features: ``(B, M, ifd_feature_dim)`` CLIP features, one row per feature some pixel shows (the
                rows of the samples' feature tables seen in a view, :meth:`KeyframePolicy.model_inputs`; any
                ``M``, zero-padded) (``ifd`` only).
            ifd_index: ``(B, V, H, W)`` int64 row of ``ifd_features`` each pixel shows, -1 where empty
                (``ifd`` only).
            pool_weights: ``(B, V, H, W)`` per-view distributions (each summing to 1) at which the
                rotation/gripper head pools tokens. Training passes the ground-truth heatmap (as
                RVT-2 does), so the head learns from the right location while the heatmap is still
                wrong; ``None`` (inference) pools at the predicted heatmap.
        """
        self._check(images, proprio, lang, mask, ifd_features, ifd_index)
        cfg, spec = self.config, self.config.spec
        b, v, _, h, w = images.shape
        g, d = cfg.grid, cfg.width
        x = images
        if spec.uses_mask and spec.mask_stage == "input":
            assert mask is not None  # checked by _check
            x = torch.cat([x, mask.to(x.dtype)], dim=2)
        # Full-resolution maps are kept channels-last (N, H, W, C): the 3x3 convolutions run in that layout (on
        # the CPU their backward pass is 2-3x faster than in the default one), and the 1x1 and patchify
        # convolutions become plain matrix products over the channels (same weights, same function).
        stem = self.stem(x.flatten(0, 1).contiguous(memory_format=CHANNELS_LAST)).permute(0, 2, 3, 1)  # (BV, H, W, C)
        parts = [stem]
        if spec.uses_mask and spec.mask_stage == "stem":
            assert mask is not None  # checked by _check
            parts.append(mask.flatten(0, 1).permute(0, 2, 3, 1).to(stem.dtype))
        if spec.clip_features:
            assert ifd_features is not None and ifd_index is not None  # checked by _check
            parts.append(self._render_features(ifd_features, ifd_index).to(stem.dtype))
        feat = stem
        if len(parts) > 1:
            assert isinstance(self.fuse, nn.Sequential)  # built whenever there is something to fuse
            feat = self.fuse[1](_pointwise(self.fuse[0], torch.cat(parts, dim=-1)))  # (BV, H, W, C)

        p = cfg.patch_size
        c = feat.shape[-1]
        patches = feat.reshape(b * v, g, p, g, p, c).permute(0, 1, 3, 2, 4, 5).reshape(b * v, g * g, p * p * c)
        weight = self.patchify.weight.permute(0, 2, 3, 1).reshape(self.patchify.out_channels, -1)
        tok = self.embed(F.linear(patches, weight, self.patchify.bias)).reshape(b, v, g * g, d)
        tok = tok + self.view_pos + self.proprio(proprio).view(b, 1, 1, d)
        tok = tok.reshape(b * v, g * g, d)
        for blk in self.within:
            tok = blk(tok)
        lang_tok = self.lang_proj(lang) + self.lang_pos
        seq = torch.cat([tok.reshape(b, v * g * g, d), lang_tok], dim=1)
        for i, blk in enumerate(self.joint):  # the last block: only the view tokens' outputs are read
            seq = blk(seq, queries=v * g * g if i == len(self.joint) - 1 else None)
        tok = self.norm(seq[:, : v * g * g]).reshape(b * v, g * g, d)

        # translation heatmap: pixel-shuffle tokens to full resolution (token t's channel k * p * p + i * p + j
        # goes to pixel (i, j) of its patch, channel k), skip-connect the fused stem features
        # (the up-projection's output rows are taken in (i, j, k) order, so the shuffle copies runs of p * dc values)
        dc = cfg.decoder_channels
        up_weight = self.up.weight.view(dc, p, p, d).permute(1, 2, 0, 3).reshape(p * p * dc, d)
        up_bias = self.up.bias.view(dc, p, p).permute(1, 2, 0).reshape(p * p * dc)
        up = F.linear(tok, up_weight, up_bias).reshape(b * v, g, g, p, p, dc).permute(0, 1, 3, 2, 4, 5)
        up = up.reshape(b * v, h, w, dc)
        fine = up + _pointwise(self.skip, feat)  # (BV, H, W, dc)
        act1, conv3, act2, conv1 = self.decode
        hidden = conv3(act1(fine).permute(0, 3, 1, 2))  # channels-last (BV, dc, H, W)
        heat = _pointwise(conv1, act2(hidden).permute(0, 2, 3, 1)).view(b, v, h, w)
        nb = cfg.rotation_bins
        if self.global_head is None:  # translation only (the coarse stage of a two-stage policy)
            return PolicyOutput(heatmap=heat, rotation=heat.new_zeros((b, 3, 0)), gripper=heat.new_zeros((b, 0)),
                                collision=heat.new_zeros((b, 0)))

        # global feature: max-pooled tokens + tokens pooled by the (detached) heatmap per view
        # (ground truth in training, prediction at inference)
        if pool_weights is None:
            prob = torch.softmax(heat.detach().float().flatten(2), -1).view(b * v, 1, h, w)
        else:
            if tuple(pool_weights.shape) != (b, v, h, w):
                raise ValueError(f"pool_weights must be (B, V, H, W) = {(b, v, h, w)}, got {tuple(pool_weights.shape)}")
            prob = pool_weights.detach().float().reshape(b * v, 1, h, w)
        weights = F.avg_pool2d(prob, p).flatten(1) * (p * p)  # (B*V, g*g), sums to 1
        pooled = torch.einsum("nt,ntd->nd", weights.to(tok.dtype), tok)
        parts = [tok.amax(1), pooled]
        if cfg.local_rotation_features:  # the decoder's per-pixel features at the heatmap, (B*V, dc)
            parts.append(torch.einsum("nhw,nhwc->nc", prob[:, 0].to(fine.dtype), fine))
        if self.crop_net is not None:  # a small CNN over the stem features around the most likely pixel
            parts.append(self.crop_net(_crop_at_mode(feat, prob[:, 0], cfg.rotation_crop)).to(tok.dtype))
        glob = torch.cat(parts, dim=-1).reshape(b, -1)
        out = self.global_head(glob)
        return PolicyOutput(
            heatmap=heat,
            rotation=out[:, : 3 * nb].reshape(b, 3, nb),
            gripper=out[:, 3 * nb : 3 * nb + 2],
            collision=out[:, 3 * nb + 2 :],
        )

    def _render_features(self, features: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
        """Project the feature rows to the stem width and gather them into the views.

        Projection and gathering commute (rendering picks one point per pixel), so projecting the
        ``M`` visible rows first is the cheap way of fusing re-rendered CLIP feature maps.

        Returns:
            ``(B*V, H, W, C)`` (channels last), zero where no point is visible.
        """
        assert self.ifd_proj is not None  # built for the variants with CLIP features
        b, v, h, w = index.shape
        proj = self.ifd_proj(features.to(self.ifd_proj.weight.dtype))  # (B, N, C)
        flat = index.reshape(b, v * h * w)
        valid = (flat >= 0).unsqueeze(-1)
        gathered = torch.gather(proj, 1, flat.clamp(min=0).unsqueeze(-1).expand(-1, -1, proj.shape[-1]))
        gathered = gathered * valid
        return gathered.view(b * v, h, w, -1)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
