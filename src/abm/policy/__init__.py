"""The policy family: an RVT-style multi-view transformer with variants chosen by config.

Main entry points:

* :class:`KeyframePolicy` — the policy object: owns the renderer, conditioning, language cache, action
  coding and network; ``compute_loss(batch)``, ``predict(batch)``, ``act(observation, instruction)``,
  ``save`` / ``from_checkpoint``.
* :class:`PolicyConfig` / :func:`PolicyConfig.from_preset` — variant (``abm``, ``rvt``, ``ifd``,
  ``stack``, ``concat-rerendered``, ``concat-full``) and size preset (``paper``, ``small``).
* :class:`MultiViewTransformer` — the one network class; :class:`PolicyOutput` its logits.
* :func:`policy_loss`, :func:`translation_targets`, :func:`decode_output` — loss and decoding.
"""

from abm.lazy import lazy_exports

# imported on first use (abm.lazy), so importing the package (every `abm` command does) stays light
__getattr__, __dir__ = lazy_exports(__name__, {
    "abm.policy.action_coding": ("EncodedAction", "decode_action", "encode_action",),
    "abm.policy.config": ("PRESETS", "PolicyConfig", "check_compatible",),
    "abm.policy.heads": ("LossTerms", "decode_output", "decode_translation", "policy_loss", "translation_targets",),
    "abm.policy.keyframe_policy": ("KeyframePolicy", "PolicyExplanation", "GroundingExplanation", "explain_grounding",),
    "abm.policy.mvt": ("MultiViewTransformer", "PolicyOutput",),
    "abm.policy.variants": ("VARIANTS", "VariantSpec", "get_variant", "mask_channel",),
})

__all__ = [
    "PRESETS", "VARIANTS", "EncodedAction", "KeyframePolicy", "LossTerms", "MultiViewTransformer", "PolicyConfig",
    "PolicyExplanation", "PolicyOutput", "GroundingExplanation", "VariantSpec", "check_compatible", "decode_action",
    "decode_output", "decode_translation", "encode_action", "explain_grounding", "get_variant", "mask_channel",
    "policy_loss", "translation_targets",
]
