"""The policy family: an RVT-style multi-view transformer with variants chosen by config.

Main entry points:

* :class:`PolicyConfig` / :func:`PolicyConfig.from_preset` — variant (``abm``, ``rvt``, ``ifd``,
  ``stack``, ``concat-rerendered``, ``concat-full``) and size preset (``paper``, ``small``).
* :class:`MultiViewTransformer` — the one model class; :class:`PolicyOutput` its logits.
* :func:`policy_loss`, :func:`translation_targets`, :func:`decode_output` — loss and decoding.
* :class:`Policy` — inference wrapper: ``Policy.load(run_or_ckpt).act(observation, instruction)``.
"""

from abm.policy.action_coding import EncodedAction, decode_action, encode_action, proprioception
from abm.policy.config import PRESETS, PolicyConfig, check_compatible
from abm.policy.heads import LossTerms, decode_output, decode_translation, policy_loss, translation_targets
from abm.policy.mvt import MultiViewTransformer, PolicyOutput
from abm.policy.variants import VARIANTS, VariantSpec, get_variant, mask_channel

__all__ = [
    "PRESETS", "VARIANTS", "EncodedAction", "LossTerms", "MultiViewTransformer", "Policy", "PolicyConfig",
    "PolicyOutput", "VariantSpec", "check_compatible", "decode_action", "decode_output", "decode_translation",
    "encode_action", "get_variant", "mask_channel", "policy_loss", "proprioception", "translation_targets",
]


def __getattr__(name: str):  # lazy: the inference wrapper pulls in the data pipeline
    if name == "Policy":
        from abm.policy.inference import Policy

        return Policy
    raise AttributeError(name)
