"""The variants of the one policy family: which extra inputs a model takes and what text it reads.

====================== ============================ ================= ==================
variant                mask input                   where it enters   language goal
====================== ============================ ================= ==================
``abm``                centre-pixel mask            after the stem    skill text T_skill
``rvt``                none                         --                full instruction
``ifd``                none; CLIP features re-      after the stem    full instruction
                       rendered into the views
``stack``              binarised re-rendered mask   extra input ch.   skill text
``concat-rerendered``  soft re-rendered mask        after the stem    skill text
``concat-full``        binarised re-rendered mask   after the stem    skill text
====================== ============================ ================= ==================

The rendered mask channel comes from re-rendering the per-point mask field (``stack``,
``concat-full``, ``abm``: binary mask; ``concat-rerendered``: the soft per-point heatmap) into the
virtual views; :func:`mask_channel` turns the rendered ``(B, V, 2, H, W)`` [mask, heatmap] pair
into the single channel a variant consumes.

**Adding a variant**: one :func:`register_variant` entry here (a new mask form also needs its branch in
:func:`mask_channel`), then ``python tests/test_policy_golden.py --update VARIANT`` records its golden outputs;
``abm train --method`` offers it from :data:`VARIANTS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from abm.registry import Registry

if TYPE_CHECKING:  # torch is imported where masks are computed, so the command line starts fast
    import torch

MaskKind = Literal["none", "center", "soft", "binary"]


@dataclass(frozen=True)
class VariantSpec:
    """Input choices of one variant.

    Attributes:
        name: variant name.
        mask: which mask form the model takes (``none``, ``center``, ``soft``, ``binary``).
        mask_stage: ``"input"`` (appended to the RVT channels before the stem) or ``"stem"``
            (concatenated with the stem features); irrelevant when ``mask == "none"``.
        clip_features: whether re-rendered per-point CLIP features are fused after the stem.
        language: ``"skill"`` (T_skill, the instruction with the object replaced by ``X``) or
            ``"instruction"`` (the full instruction).
    """

    name: str
    mask: MaskKind
    mask_stage: Literal["input", "stem"]
    clip_features: bool
    language: Literal["skill", "instruction"]

    @property
    def uses_mask(self) -> bool:
        return self.mask != "none"

    @property
    def needs_grounding(self) -> bool:
        """Whether the variant needs a grounder (a per-point mask field) at train and test time."""
        return self.uses_mask


#: every policy variant, by name (``abm train --method`` choices, ``PolicyConfig.variant``)
VARIANTS: Registry[VariantSpec] = Registry("policy variant")


def register_variant(spec: VariantSpec) -> VariantSpec:
    """Add a variant to :data:`VARIANTS` under its name."""
    return VARIANTS.register(spec.name, spec)


register_variant(VariantSpec("abm", "center", "stem", False, "skill"))
register_variant(VariantSpec("rvt", "none", "stem", False, "instruction"))
register_variant(VariantSpec("ifd", "none", "stem", True, "instruction"))
register_variant(VariantSpec("stack", "binary", "input", False, "skill"))
register_variant(VariantSpec("concat-rerendered", "soft", "stem", False, "skill"))
register_variant(VariantSpec("concat-full", "binary", "stem", False, "skill"))


def get_variant(name: str) -> VariantSpec:
    """The :class:`VariantSpec` called ``name``; a ``ValueError`` listing the known ones otherwise
    (:class:`abm.registry.UnknownNameError`)."""
    return VARIANTS[name]


def mask_channel(spec: VariantSpec, rendered: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """The one mask channel a variant consumes, from the rendered mask-field channels.

    Args:
        spec: the variant.
        rendered: ``(B, V, 2, H, W)`` re-rendered per-point ``[mask, heatmap]`` (background 0).
        threshold: binarisation threshold.

    Returns:
        ``(B, V, 1, H, W)`` float mask: centre pixel (``abm``), soft heatmap (``concat-rerendered``)
        or binarised mask (``stack``, ``concat-full``).
    """
    import torch

    from abm.render import binarize_mask, center_pixel_mask, soft_mask  # torch: policy.config builds parsers

    if rendered.dim() != 5 or rendered.shape[2] != 2:
        raise ValueError(f"rendered mask channels must be (B, V, 2, H, W), got {tuple(rendered.shape)}")
    if spec.mask == "center":
        out = center_pixel_mask(binarize_mask(rendered[:, :, 0], threshold))
    elif spec.mask == "soft":
        out = soft_mask(rendered[:, :, 1])
    elif spec.mask == "binary":
        out = binarize_mask(rendered[:, :, 0], threshold)
    else:
        raise ValueError(f"variant {spec.name!r} takes no mask")
    channel: torch.Tensor = out.unsqueeze(2).to(torch.float32)
    return channel
