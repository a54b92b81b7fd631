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

from abm.policy.action_coding import EncodedAction, decode_action, encode_action
from abm.policy.config import PRESETS, PolicyConfig, check_compatible
from abm.policy.heads import LossTerms, decode_output, decode_translation, policy_loss, translation_targets
from abm.policy.keyframe_policy import KeyframePolicy, PolicyExplanation
from abm.policy.mvt import MultiViewTransformer, PolicyOutput
from abm.policy.variants import VARIANTS, VariantSpec, get_variant, mask_channel

__all__ = [
    "PRESETS", "VARIANTS", "EncodedAction", "KeyframePolicy", "LossTerms", "MultiViewTransformer", "PolicyConfig",
    "PolicyExplanation", "PolicyOutput", "VariantSpec", "check_compatible", "decode_action", "decode_output",
    "decode_translation", "encode_action", "get_variant", "mask_channel", "policy_loss", "translation_targets",
]
