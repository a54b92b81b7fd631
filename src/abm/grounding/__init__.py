"""Grounding: CLIP dense features, the CLIP Feature Cloud, the Object Mask Field and the grounders that mark the
instruction's object in a point cloud (the instruction itself is read by :mod:`abm.language`).

Typical use::

    from abm.grounding import ClipGrounderConfig, build_grounder, mask_views
    from abm.language import decompose_instruction

    target, skill = decompose_instruction("put the tomato in the plate")   # "tomato", "put X in the plate"
    grounder = build_grounder(ClipGrounderConfig(model="openai/clip-vit-large-patch14-336"))  # or {"kind": "oracle"}
    field = grounder.ground(observation, cloud, target, episode.object_names)  # MaskField over cloud points
    views = mask_views(renderer, cloud, field.mask)                           # center-pixel masks (V, H, W)

transformers is imported only when a CLIP model is built, so the oracle grounder works without it.
"""

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.grounding.cache import GroundingCache, cloud_key, content_key, frame_key, image_key
    from abm.grounding.clip import (
        CLIP_PRESETS,
        ClipBackbone,
        ClipWeightsNotFoundError,
        load_clip,
        model_fingerprint,
        random_clip,
        tiny_clip,
    )
    from abm.grounding.config import (
        DEFAULT_MODEL,
        DEFAULT_NEGATIVES,
        DEFAULT_NORMALIZATION,
        DEFAULT_THRESHOLD,
        GROUNDERS,
        NORMALIZATIONS,
        ClipGrounderConfig,
        ClipModelConfig,
        GrounderConfig,
        MaskFieldConfig,
        OracleGrounderConfig,
        TrackingGrounderConfig,
        build_grounder,
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
        match_object_ids,
        target_point_mask,
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

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "DEFAULT_MODEL", "DEFAULT_NEGATIVES", "MIN_CONFIDENCE", "GroundingRecorder", "TargetDecision", "decide_target",
    "normalize_name", "target_candidates", "mask_confidence", "DEFAULT_NORMALIZATION", "DEFAULT_THRESHOLD", "GROUNDERS",
    "NORMALIZATIONS", "CLIP_PRESETS", "ClipBackbone", "ClipGrounder", "ClipGrounderConfig", "ClipModelConfig",
    "ClipWeightsNotFoundError", "FeatureCloud", "Grounder", "GrounderConfig", "GroundingCache", "MaskField",
    "MaskFieldConfig", "MaskViews", "OracleGrounder", "OracleGrounderConfig", "TrackingGrounderConfig",
    "build_feature_cloud", "build_grounder", "cloud_key", "content_key", "frame_key", "image_key",
    "lift_patch_features", "load_clip", "mask_field_from_features", "mask_views", "match_object_ids",
    "model_fingerprint", "nearest_patch_index", "normalize_heatmap", "random_clip", "target_point_mask",
    "threshold_heatmap", "tiny_clip", "upsample_nearest",
]
