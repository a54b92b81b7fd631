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

from typing import TYPE_CHECKING

from abm.lazy import lazy_exports

if TYPE_CHECKING:  # the exports; at run time each is imported on first use (abm.lazy), so importing the
    # package (every `abm` command does) stays light
    from abm.policy.action_coding import EncodedAction, decode_action, encode_action
    from abm.policy.config import PRESETS, PolicyConfig, check_compatible
    from abm.policy.heads import LossTerms, decode_output, decode_translation, policy_loss, translation_targets
    from abm.policy.keyframe_policy import GroundingExplanation, KeyframePolicy, PolicyExplanation, explain_grounding
    from abm.policy.mvt import MultiViewTransformer, PolicyOutput
    from abm.policy.variants import VARIANTS, VariantSpec, get_variant, mask_channel

__getattr__, __dir__ = lazy_exports(__name__, __file__)

__all__ = [
    "PRESETS", "VARIANTS", "EncodedAction", "KeyframePolicy", "LossTerms", "MultiViewTransformer", "PolicyConfig",
    "PolicyExplanation", "PolicyOutput", "GroundingExplanation", "VariantSpec", "check_compatible", "decode_action",
    "decode_output", "decode_translation", "encode_action", "explain_grounding", "get_variant", "mask_channel",
    "policy_loss", "translation_targets",
]
