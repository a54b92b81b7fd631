"""Language goals for the policy: a small encoder interface and its implementations.

The policy reads ``L`` language-token embeddings of width ``D`` (77 x 512 for CLIP ViT-B text
features, 77 x 768 for ViT-L). Encoders are described by a JSON-compatible *spec* stored in every
checkpoint so :class:`~abm.policy.KeyframePolicy` can rebuild the same encoder:

* ``{"kind": "hash", "dim": D, "tokens": L, "seed": s}`` — :class:`HashLanguageEncoder`, a frozen,
  weight-free encoder: every lower-cased word maps to a fixed pseudo-random unit vector (seeded by a
  CRC32 of the word) plus a fixed position vector. It distinguishes instructions by their words, needs
  no download, and is what tests and CPU experiments use.
* ``{"kind": "clip", "model": ...}`` — CLIP text tokens of a CLIP model's text tower (the paper's choice), see
  :class:`ClipLanguageEncoder`.

Their typed configurations and the registry of kinds are :mod:`abm.policy.language_config` (light, for the
command line); each encoder here is built from its configuration by ``from_config``.
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import torch
from numpy.typing import NDArray

from abm.errors import ConfigError
from abm.grounding.clip import load_clip_model
from abm.policy.language_config import ClipLanguageConfig, HashLanguageConfig

_WORD = re.compile(r"[a-z0-9]+")


class LanguageEncoder(Protocol):
    """Texts -> ``(B, tokens, dim)`` float32 token embeddings (frozen)."""

    tokens: int
    dim: int

    def encode(self, texts: Sequence[str]) -> torch.Tensor: ...

    def spec(self) -> dict[str, Any]: ...


class TextTower(Protocol):
    """What :class:`ClipLanguageEncoder` needs of a CLIP (:class:`abm.grounding.clip.ClipBackbone` has it)."""

    def text_tokens(self, texts: Sequence[str]) -> torch.Tensor: ...


class HashLanguageEncoder:
    """Weight-free deterministic word embeddings (see module docstring).

    Args:
        dim: embedding width ``D``.
        tokens: sequence length ``L`` (texts longer than ``L`` words are truncated; the rest is 0).
        seed: changes every vector.
    """

    def __init__(self, dim: int = 512, tokens: int = 77, seed: int = 0) -> None:
        self.dim, self.tokens, self.seed = int(dim), int(tokens), int(seed)
        if self.dim < 1 or self.tokens < 1:
            raise ConfigError(f"the hash encoder needs dim and tokens >= 1, got {self.dim} and {self.tokens}")
        rng = np.random.default_rng([self.seed, 1])
        self._pos = rng.standard_normal((self.tokens, self.dim)).astype(np.float32) * 0.1

    @classmethod
    def from_config(cls, config: HashLanguageConfig) -> HashLanguageEncoder:
        """The encoder of its configuration (an unset ``dim`` is 512)."""
        return cls(512 if config.dim is None else config.dim, config.tokens, config.seed)

    def _word(self, word: str) -> NDArray[np.float32]:
        rng = np.random.default_rng([self.seed, zlib.crc32(word.encode())])
        vec = rng.standard_normal(self.dim).astype(np.float32)
        return vec / np.linalg.norm(vec)

    def encode(self, texts: Sequence[str]) -> torch.Tensor:
        """``(B, tokens, dim)``."""
        out = np.zeros((len(texts), self.tokens, self.dim), np.float32)
        for i, text in enumerate(texts):
            words = _WORD.findall(text.lower())[: self.tokens]
            for j, word in enumerate(words):
                out[i, j] = self._word(word) + self._pos[j]
        return torch.from_numpy(out)

    def spec(self) -> dict[str, Any]:
        return {"kind": "hash", "dim": self.dim, "tokens": self.tokens, "seed": self.seed}


class ClipLanguageEncoder:
    """CLIP text tokens: the text tower's last hidden states ``(B, 77, D_text)`` (float32, CPU), memoised per text.

    Args:
        backbone: a CLIP with ``text_tokens(texts) -> (B, 77, D)`` (:class:`~abm.grounding.clip.ClipBackbone`).
        spec: the options it was built from (stored in checkpoints).
    """

    def __init__(self, backbone: TextTower, spec: dict[str, Any]) -> None:
        self.backbone = backbone
        self._spec = dict(spec)
        self._rows: dict[str, NDArray[np.float32]] = {}
        probe = self.encode(["x"])
        self.tokens, self.dim = int(probe.shape[1]), int(probe.shape[2])

    @classmethod
    def from_config(cls, config: ClipLanguageConfig) -> ClipLanguageEncoder:
        """The text tower of the CLIP model its configuration names."""
        return cls(load_clip_model(config.clip), config.to_dict())

    def encode(self, texts: Sequence[str]) -> torch.Tensor:
        """``(B, tokens, dim)``; the texts not seen before are encoded in one batch, in order."""
        todo = [t for t in dict.fromkeys(texts) if t not in self._rows]
        if todo:
            with torch.no_grad():
                tokens = self.backbone.text_tokens(todo).cpu().numpy()
            self._rows.update(zip(todo, tokens, strict=True))
        return torch.from_numpy(np.stack([self._rows[t] for t in texts]).astype(np.float32))

    def spec(self) -> dict[str, Any]:
        return dict(self._spec)
