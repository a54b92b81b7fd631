"""An offline CLIP tokenizer for randomly initialised models (tests, speed measurements).

Real CLIP weights come with their own tokenizer files. Random models have none, so this module
generates a character-level byte-BPE vocabulary (the 256 byte symbols, each also with CLIP's
end-of-word suffix ``</w>``, plus the start/end tokens) and no merges, writes ``vocab.json`` and
``merges.txt`` to a temporary folder once per process and loads it with transformers'
:class:`~transformers.CLIPTokenizer`. The call interface (``tokenizer(texts, padding=...,
max_length=..., truncation=..., return_tensors="pt")``) is that of any CLIP tokenizer.
"""

from __future__ import annotations

import functools
import json
import tempfile
from pathlib import Path
from typing import Any

BOS_TOKEN = "<|startoftext|>"
EOS_TOKEN = "<|endoftext|>"


def char_vocab() -> dict[str, int]:
    """Token -> id for the character-level vocabulary (ids 0..513; BOS = 512, EOS = 513)."""
    from tokenizers.pre_tokenizers import ByteLevel

    symbols = sorted(ByteLevel.alphabet())
    vocab = {s: i for i, s in enumerate(symbols)}
    vocab.update({s + "</w>": len(symbols) + i for i, s in enumerate(symbols)})
    vocab[BOS_TOKEN] = len(vocab)
    vocab[EOS_TOKEN] = len(vocab)
    return vocab


@functools.lru_cache(maxsize=1)
def tiny_tokenizer() -> Any:
    """A :class:`transformers.CLIPTokenizer` over :func:`char_vocab` (works offline; cached)."""
    from transformers import CLIPTokenizer

    folder = Path(tempfile.mkdtemp(prefix="abm_clip_tokenizer_"))
    (folder / "vocab.json").write_text(json.dumps(char_vocab()), encoding="utf-8")
    (folder / "merges.txt").write_text("#version: 0.2\n", encoding="utf-8")
    return CLIPTokenizer.from_pretrained(str(folder), local_files_only=True)
