"""Configuration of the multi-view transformer: variant (which inputs) and sizes (preset).

One :class:`PolicyConfig` describes a model completely; it is stored in every checkpoint, and a
checkpoint only loads into a model built from an equal config (see :func:`check_compatible`).

Presets (``PolicyConfig.from_preset``):

========== ====== ========= ====== ============ ======= ================ ===========
preset     views  view res  patch  tokens/view  width   layers (in/joint) stem ch.
========== ====== ========= ====== ============ ======= ================ ===========
``paper``  5      220       11     20 x 20      512     8 (4 / 4)        64
``small``  5      96        8      12 x 12      128     4 (2 / 2)        32
========== ====== ========= ====== ============ ======= ================ ===========

Both use 77 language tokens, 72 rotation bins per Euler axis (5 degrees), 2-way gripper and
ignore-collision heads. ``small`` is sized from docs/notes on a 2-core CPU (~8 samples/s training).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any, cast

from abm.configuration import MAX_KEYFRAMES
from abm.policy.variants import VARIANTS, VariantSpec, get_variant

PRESETS: dict[str, dict[str, float]] = {
    "paper": dict(resolution=220, patch_size=11, width=512, layers_within=4, layers_joint=4, heads=8,
                  stem_channels=64, decoder_channels=16, mlp_ratio=4.0),
    "small": dict(resolution=96, patch_size=8, width=128, layers_within=2, layers_joint=2, heads=4,
                  stem_channels=32, decoder_channels=16, mlp_ratio=2.0),
}


@dataclass
class PolicyConfig:
    """Everything that determines the shapes of a :class:`~abm.policy.mvt.MultiViewTransformer`.

    Attributes:
        variant: ``abm``, ``rvt``, ``ifd``, ``stack``, ``concat-rerendered`` or ``concat-full``
            (see :mod:`abm.policy.variants`).
        preset: the preset the sizes came from (``paper``, ``small`` or ``custom``); informational
            but checked on checkpoint loading.
        num_views: number of virtual views ``V`` (the renderer's views, in order).
        views: names of the virtual views.
        resolution: side ``H = W`` of every view in pixels.
        patch_size: side of a token's patch in pixels; must divide ``resolution``.
        width: transformer width ``d``.
        layers_within: attention layers applied to each view's tokens separately.
        layers_joint: attention layers over all views' tokens plus the language tokens.
        heads: attention heads (must divide ``width``).
        mlp_ratio: hidden size of the transformer MLP relative to ``width``.
        stem_channels: channels of the full-resolution conv stem.
        decoder_channels: channels of the up-sampled heatmap decoder (per pixel).
        image_channels: RVT input channels per view (rgb 3, depth 1, xyz 3, pixel location 3).
        lang_tokens: language tokens ``L`` (77 for CLIP).
        lang_dim: dimension of the language token embeddings.
        ifd_feature_dim: dimension of the per-point CLIP features (``ifd`` only).
        proprio_dim: proprioception size (gripper open, gripper position in cube coordinates); the network's
            input is :attr:`proprio_size` (with the progress input).
        rotation_bins: bins per Euler axis.
        local_rotation_features: also feed the rotation/gripper head the full-resolution decoder features
            (``decoder_channels`` per view) pooled with the heatmap at the pixel level, not only the
            patch tokens (a token spans ``patch_size`` pixels: 12.5 cm at 64² views over the 1 m cube,
            wider than most objects whose yaw the approach has to read).
        rotation_crop: side (pixels, a multiple of 4; 0 = off) of a crop of every view's full-resolution stem
            features, centred on the heatmap's most likely pixel (the label's in training), that a small CNN
            shared by the views reads for the rotation/gripper head. The crop keeps the object's outline at
            the view's full resolution, which the patch tokens blur (16 px at 64² views over the 1 m cube is a
            25 cm square; at a 32² zoom over 0.3 m, 15 cm).
        zoom_size: edge (m) of the zoomed cube of the second stage; 0 = one stage. With a zoom, a coarse
            stage predicts only the translation heatmap over the workspace; the cloud is then re-rendered into
            the same views over a cube of this edge around the coarse point (the label plus ``zoom_noise`` in
            training, the coarse prediction at inference), and a second network of the same family predicts
            the translation inside the zoom, the rotation, gripper and collision from those views (RVT-2's
            coarse-to-fine scheme).
        zoom_resolution: pixels per side of the zoomed views.
        zoom_patch_size: token patch side (pixels) of the zoomed stage; must divide ``zoom_resolution``.
        zoom_noise: training only: the zoom centre is the label plus uniform noise in ``[-zoom_noise,
            zoom_noise]`` m per axis, so the fine stage learns to correct a coarse point that is off by as much.
        destination_mask: mask variants (abm and the ablations): a second mask channel beside the target's, the
            destination's mask field (the plate, the target pad, the wine rack; ``Task.destination``) in the
            variant's mask form, grounded by the same grounder (:func:`abm.grounding.conditioning.condition_cloud`).
            Off: the paper's one mask; checkpoints without the field read as off.
        progress_input: every variant: the proprioception also holds the task's progress, the keyframe index
            (``Observation.step``) divided by ``progress_budget`` and clipped to 1, as RVT feeds its time step. (The
            finger state is fed already: ``gripper_open``, the proprioception's first entry, is the measured finger
            opening normalised to ``[0, 1]``.) Off: checkpoints without the field read as off.
        progress_budget: keyframes the progress input is normalised by (the evaluation's keyframe budget, the
            same number in training and at inference).
        dropout: dropout in attention / MLP.
        workspace_center: workspace cube centre (m), used for action decoding.
        workspace_size: workspace cube edge (m).
        extra: free-form notes stored with the config (not used by the model, ignored when comparing).
    """

    variant: str = "abm"
    preset: str = "small"
    views: tuple[str, ...] = ("front", "back", "left", "right", "top")
    resolution: int = field(default=96, metadata={"flag": "--view-resolution"})
    patch_size: int = 8
    width: int = 128
    layers_within: int = 2
    layers_joint: int = 2
    heads: int = 4
    mlp_ratio: float = 2.0
    stem_channels: int = 32
    decoder_channels: int = 16
    image_channels: int = field(default=10, metadata={"cli": False})  # fixed by the renderer
    lang_tokens: int = field(default=77, metadata={"cli": False})  # set by the language encoder
    lang_dim: int = 512
    ifd_feature_dim: int = 512
    proprio_dim: int = field(default=4, metadata={"cli": False})  # fixed by the policy
    rotation_bins: int = 72
    local_rotation_features: bool = False
    rotation_crop: int = 0
    zoom_size: float = 0.0
    zoom_resolution: int = 32
    zoom_patch_size: int = 4
    zoom_noise: float = 0.03
    destination_mask: bool = False
    progress_input: bool = False
    progress_budget: int = MAX_KEYFRAMES
    dropout: float = 0.0
    workspace_center: tuple[float, float, float] = (0.5, 0.0, 0.35)
    workspace_size: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict, metadata={"cli": False})

    def __post_init__(self) -> None:
        get_variant(self.variant)  # raises on an unknown variant
        self.views = tuple(self.views)
        self.workspace_center = cast("tuple[float, float, float]", tuple(float(c) for c in self.workspace_center))
        if self.resolution % self.patch_size:
            raise ValueError(f"patch_size {self.patch_size} must divide the view resolution {self.resolution}")
        if self.width % self.heads:
            raise ValueError(f"heads {self.heads} must divide width {self.width}")
        if self.layers_within < 0 or self.layers_joint < 0 or self.layers_within + self.layers_joint == 0:
            raise ValueError("the transformer needs at least one layer")
        if not self.zoom_size >= 0.0 or self.zoom_size >= self.workspace_size:
            raise ValueError(f"zoom_size must be in [0, workspace_size = {self.workspace_size}) m (0 = one stage), "
                             f"got {self.zoom_size}")
        if self.zoom_resolution % self.zoom_patch_size:
            raise ValueError(f"zoom_patch_size {self.zoom_patch_size} must divide zoom_resolution "
                             f"{self.zoom_resolution}")
        if self.zoom_size and not 0.0 <= self.zoom_noise < self.zoom_size / 2:
            raise ValueError(f"zoom_noise must be in [0, zoom_size / 2 = {self.zoom_size / 2:g}) m, "
                             f"got {self.zoom_noise}")
        if self.rotation_crop < 0 or self.rotation_crop % 4 or self.rotation_crop > min(
                self.resolution, self.zoom_resolution if self.zoom_size else self.resolution):
            raise ValueError(f"rotation_crop must be 0 (off) or a multiple of 4 pixels no larger than the views, "
                             f"got {self.rotation_crop}")
        if 360 % self.rotation_bins:
            raise ValueError(f"rotation_bins must divide 360, got {self.rotation_bins}")
        if self.destination_mask and not self.spec.uses_mask:
            raise ValueError(f"destination_mask is a second mask channel: variant {self.variant!r} takes no mask "
                             f"(mask variants: {sorted(n for n, v in VARIANTS.items() if v.uses_mask)})")
        if self.progress_budget < 1:
            raise ValueError(f"progress_budget must be at least 1 keyframe, got {self.progress_budget}")

    # ------------------------------------------------------------------ helpers
    @property
    def spec(self) -> VariantSpec:
        """The input/conditioning choices of this config's variant."""
        return get_variant(self.variant)

    @property
    def num_views(self) -> int:
        return len(self.views)

    @property
    def mask_channels(self) -> int:
        """Mask channels of every view: 0 (rvt, ifd), 1 (the target's) or 2 (and the destination's)."""
        return 0 if not self.spec.uses_mask else 2 if self.destination_mask else 1

    @property
    def proprio_size(self) -> int:
        """Width of the network's proprioception input: ``proprio_dim`` plus the progress input's one entry."""
        return self.proprio_dim + (1 if self.progress_input else 0)

    @property
    def grid(self) -> int:
        """Tokens per view side (``resolution // patch_size``)."""
        return self.resolution // self.patch_size

    @property
    def two_stage(self) -> bool:
        """Whether a zoomed second stage follows the coarse one (``zoom_size > 0``)."""
        return self.zoom_size > 0.0

    def zoom_config(self) -> PolicyConfig:
        """The config of the zoomed stage's network: this one at the zoom's resolution and patch, over a cube of
        edge ``zoom_size`` centred at the origin (the zoomed cloud is shifted so its centre is the origin)."""
        if not self.two_stage:
            raise ValueError("this policy has one stage (zoom_size = 0)")
        return dataclasses.replace(self, resolution=self.zoom_resolution, patch_size=self.zoom_patch_size,
                                   workspace_center=(0.0, 0.0, 0.0), workspace_size=self.zoom_size, zoom_size=0.0)

    @classmethod
    def from_preset(cls, preset: str, variant: str = "abm", **overrides: object) -> PolicyConfig:
        """Config of a size preset (``paper`` or ``small``) for one variant; ``overrides`` replace fields.

        A config with overridden sizes keeps the preset name with ``+custom`` appended so a
        checkpoint tells how it was built.
        """
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose from {sorted(PRESETS)}")
        values: dict[str, Any] = dict(PRESETS[preset])
        size_keys = set(values) | {"views", "lang_tokens", "rotation_bins", "local_rotation_features", "rotation_crop",
                                   "zoom_size",
                                   "zoom_resolution", "zoom_patch_size"}
        name = preset + ("+custom" if any(k in size_keys for k in overrides) else "")
        values.update(overrides)
        return cls(variant=variant, preset=name, **values)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-compatible dict (tuples become lists)."""
        out = dataclasses.asdict(self)
        out["views"] = list(self.views)
        out["workspace_center"] = list(self.workspace_center)
        return out

    def preset_changes(self) -> dict[str, Any]:
        """The fields (JSON form, in field order) where this config differs from its preset's for its variant
        (:meth:`from_preset`; ``extra`` left out): what a recipe's ``policy:`` or ``--set`` gives to build it again."""
        preset = self.preset.split("+")[0]
        base = PolicyConfig.from_preset(preset, self.variant).to_dict() if preset in PRESETS else {}
        return {k: v for k, v in self.to_dict().items()
                if k not in ("variant", "preset", "extra") and (k not in base or v != base[k])}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PolicyConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise a clear error."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown policy config fields {unknown}")
        return cls(**data)


def check_compatible(stored: PolicyConfig, wanted: PolicyConfig, source: str | None = None) -> None:
    """Raise ``ValueError`` naming the checkpoint (``source``), each differing field with both values, and the
    fix, when a checkpoint's config does not match a model's."""
    where = f"{source}: " if source else ""
    if stored.variant != wanted.variant:
        raise ValueError(
            f"{where}checkpoint is of variant {stored.variant!r} but the model is {wanted.variant!r}; "
            f"train or load a {wanted.variant!r} checkpoint (known variants: {sorted(VARIANTS)})"
        )
    a, b = stored.to_dict(), wanted.to_dict()
    fields = [k for k in a if k not in ("extra", "preset") and a[k] != b.get(k)]
    if fields:
        diffs = "; ".join(f"{k}: checkpoint {a[k]!r}, model {b.get(k)!r}" for k in fields)
        sets = " ".join(f"--set {k}={json.dumps(a[k], separators=(',', ':'))}" for k in fields)
        raise ValueError(
            f"{where}the checkpoint was trained with other policy settings than this model in {len(fields)} "
            f"field(s): {diffs}. Build the model with the checkpoint's values ({sets}), or train a new run into "
            "another folder"
        )
