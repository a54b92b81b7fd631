"""Grounding: instruction decomposition, CLIP dense features, CLIP Feature Cloud, Object Mask Field.

Typical use::

    from abm.grounding import decompose_instruction, make_grounder, mask_views, resolve_instruction

    target, skill = decompose_instruction("put the tomato in the plate")   # "tomato", "put X in the plate"
    resolve_instruction("grab the yellow one", ["target", "red block", "yellow block"]).canonical
    # -> "put the yellow block on the target" (plain words onto the scene's objects; abm.grounding.resolve)
    grounder = make_grounder("clip", model="openai/clip-vit-large-patch14-336")  # or make_grounder("oracle")
    field = grounder.ground(observation, cloud, target, episode.object_names)  # MaskField over cloud points
    views = mask_views(renderer, cloud, field.mask)                           # center-pixel masks (V, H, W)

transformers is imported only when a CLIP model is built, so the oracle grounder and the instruction
parser work without it.
"""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.grounding.cache import GroundingCache, cloud_key, content_key, frame_key, image_key
    from abm.grounding.clip import (
        CLIP_PRESETS,
        DEFAULT_MODEL,
        ClipBackbone,
        ClipWeightsNotFoundError,
        load_clip,
        model_fingerprint,
        random_clip,
        tiny_clip,
    )
    from abm.grounding.config import (
        DEFAULT_NEGATIVES,
        DEFAULT_NORMALIZATION,
        DEFAULT_THRESHOLD,
        GROUNDERS,
        NORMALIZATIONS,
        MaskFieldConfig,
    )
    from abm.grounding.decision import (
        MIN_CONFIDENCE,
        GroundingRecorder,
        TargetDecision,
        decide_target,
        normalize_name,
        target_candidates,
    )
    from abm.grounding.feature_cloud import (
        FeatureCloud,
        build_feature_cloud,
        lift_patch_features,
        nearest_patch_index,
        upsample_nearest,
    )
    from abm.grounding.grounders import (
        ClipGrounder,
        Grounder,
        OracleGrounder,
        make_grounder,
        match_object_ids,
        target_point_mask,
    )
    from abm.grounding.instruction import (
        InstructionError,
        InstructionParser,
        NotOneCommandError,
        ParsedInstruction,
        RewritingParser,
        TemplateParser,
        TemplateSet,
        clip_prompt,
        decompose_instruction,
        load_templates,
        normalize_instruction,
        require_instruction,
    )
    from abm.grounding.mask_field import (
        MaskField,
        MaskViews,
        mask_confidence,
        mask_field_from_features,
        mask_views,
        normalize_heatmap,
        threshold_heatmap,
    )
    from abm.grounding.resolve import (
        RESOLVE_MIN_CONFIDENCE,
        Resolution,
        UnresolvedInstructionError,
        resolve_instruction,
    )

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "DEFAULT_MODEL", "DEFAULT_NEGATIVES", "MIN_CONFIDENCE", "GroundingRecorder", "TargetDecision", "decide_target",
    "normalize_name", "target_candidates", "mask_confidence", "DEFAULT_NORMALIZATION", "DEFAULT_THRESHOLD", "GROUNDERS",
    "NORMALIZATIONS", "CLIP_PRESETS", "ClipBackbone", "ClipGrounder", "ClipWeightsNotFoundError", "FeatureCloud",
    "Grounder", "GroundingCache", "InstructionError", "InstructionParser", "MaskField", "MaskFieldConfig",
    "MaskViews", "NotOneCommandError", "OracleGrounder", "ParsedInstruction", "RewritingParser", "TemplateParser",
    "TemplateSet",
    "build_feature_cloud", "clip_prompt", "cloud_key", "content_key", "decompose_instruction", "frame_key",
    "image_key", "lift_patch_features", "load_clip", "load_templates", "make_grounder", "mask_field_from_features",
    "mask_views", "match_object_ids", "model_fingerprint", "nearest_patch_index", "normalize_heatmap",
    "normalize_instruction", "random_clip", "require_instruction",
    "RESOLVE_MIN_CONFIDENCE", "Resolution", "UnresolvedInstructionError", "resolve_instruction",
    "target_point_mask", "threshold_heatmap", "tiny_clip", "upsample_nearest",
]
