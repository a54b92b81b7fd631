"""Frozen CLIP backbone (transformers :class:`~transformers.CLIPModel`) with MaskCLIP dense features.

Three things are computed, all without gradients:

* :meth:`ClipBackbone.dense_features` — MaskCLIP patch features ``(B, h, w, D)``: every vision block
  but the last runs normally; in the last block the query-key attention is skipped and the value path
  ``out_proj(v_proj(layer_norm1(x)))`` is used alone (no residual, no MLP); the CLS token is dropped,
  then the final LayerNorm (``post_layernorm``) and the visual projection are applied and every patch
  feature is L2-normalised.
* :meth:`ClipBackbone.text_features` — projected, L2-normalised text features ``(B, D)``.
* :meth:`ClipBackbone.text_tokens` — the ``77 x D_text`` token embeddings (last hidden state of the
  text encoder after its final LayerNorm, before the projection), for the policy's language tokens.

Weights: :func:`load_clip` takes a hub name (default ``openai/clip-vit-large-patch14-336``) or a local
directory and never downloads unless ``allow_download=True``; missing weights raise
:class:`ClipWeightsNotFoundError` explaining how to provide them. :func:`tiny_clip` builds a tiny random
model for tests and :func:`random_clip` full-size random models (``"vit-b16"``, ``"vit-l14-336"``) for
speed measurements (same cost as the real ones).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Union

import numpy as np
import torch
import torch.nn.functional as F

from abm.configuration import TEST_ONLY_CLIP
from abm.errors import ConfigError, ExternalError
from abm.files import sha256_file
from abm.grounding.config import DEFAULT_MODEL, DENSE_MODES, ClipModelConfig
from abm.grounding.tokenizer import tiny_tokenizer

if TYPE_CHECKING:  # transformers is imported where a model is built, so importing abm stays fast
    from transformers.models.clip.modeling_clip import CLIPAttention, CLIPEncoderLayer

TEXT_CONTEXT = 77
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
ClipImages = Union[np.ndarray, Sequence[np.ndarray], torch.Tensor]  # noqa: UP007
"""Images for the backbone: a ``uint8`` ``(B, H, W, 3)`` array, ``uint8`` ``(H, W, 3)`` arrays (sizes may differ),
or a float ``(B, 3, H, W)`` tensor in ``[0, 1]``."""

# Architectures of the public OpenAI checkpoints, for random-weight speed measurements.
CLIP_PRESETS: dict[str, dict[str, Any]] = {
    "vit-b16": dict(
        projection_dim=512,
        vision=dict(hidden_size=768, intermediate_size=3072, num_hidden_layers=12, num_attention_heads=12,
                    image_size=224, patch_size=16),
        text=dict(hidden_size=512, intermediate_size=2048, num_hidden_layers=12, num_attention_heads=8),
    ),
    "vit-l14-336": dict(
        projection_dim=768,
        vision=dict(hidden_size=1024, intermediate_size=4096, num_hidden_layers=24, num_attention_heads=16,
                    image_size=336, patch_size=14),
        text=dict(hidden_size=768, intermediate_size=3072, num_hidden_layers=12, num_attention_heads=12),
    ),
    "tiny": dict(
        projection_dim=16,
        vision=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                    image_size=64, patch_size=8),
        text=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2),
    ),
}


class ClipWeightsNotFoundError(ExternalError, FileNotFoundError):
    """Pretrained CLIP weights are not available on this machine."""


def _missing_weights_message(name: str, reason: str) -> str:
    """One line (the ``abm: error:`` line of every command): what is missing and how to provide it."""
    if _is_local_path(name):
        fix = ("give a folder written by `abm clip train --out DIR` or by CLIPModel/CLIPTokenizer.save_pretrained, "
               "or a hub name such as openai/clip-vit-base-patch16")
    else:
        fix = (f"fetch them once on a connected machine with `huggingface-cli download {name}` and point HF_HOME "
               "at that cache, or allow the download (--allow-download / allow_download=True), or pass a local "
               "directory saved with save_pretrained or trained with `abm clip train --out DIR`")
    return (f"CLIP weights {name!r} are not available on this machine ({reason}): {fix}; in simulation "
            "--grounder oracle needs no weights (docs/grounding.md)")


def _is_local_path(name: str) -> bool:
    return Path(name).expanduser().exists() or name.startswith((".", "/", "~")) or name.count("/") > 1


# the files of a saved CLIP that its outputs depend on (logs and notes beside them are not)
_MODEL_FILES = ("config.json", "preprocessor_config.json", "tokenizer.json", "tokenizer_config.json", "vocab.json",
                "merges.txt", "special_tokens_map.json")
_WEIGHT_PATTERNS = ("*.safetensors", "*.bin")
_fingerprints: dict[tuple[object, ...], str] = {}


def model_fingerprint(name_or_path: str) -> str:
    """What a CLIP's outputs depend on, for grounding-cache keys.

    A local folder is identified by its content, not its path: ``"sha256:<16 hex>"`` over its weight,
    configuration and tokenizer files (names and bytes), so a moved or copied model reuses its cache entries
    and a model retrained into the same folder never reads the old one's. The digest is memoised by the files'
    sizes and modification times. A hub name is ``"NAME@REVISION"`` when its snapshot is in the local cache,
    else the name; ``"tiny"`` and ``"random:..."`` (fixed seeds) are their own names.
    """
    if name_or_path == "tiny" or name_or_path.startswith("random:"):
        return name_or_path
    folder = Path(name_or_path).expanduser()
    if folder.is_dir():
        files = sorted({f for f in folder.iterdir() if f.is_file() and f.name in _MODEL_FILES}
                       | {f for pattern in _WEIGHT_PATTERNS for f in folder.glob(pattern) if f.is_file()})
        if not files:
            return name_or_path
        stamp = (str(folder.resolve()), *((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files))
        if stamp not in _fingerprints:
            listing = "".join(f"{f.name}\x00{sha256_file(f)}\x00" for f in files)
            _fingerprints[stamp] = "sha256:" + hashlib.sha256(listing.encode()).hexdigest()[:16]
        return _fingerprints[stamp]
    if _is_local_path(name_or_path):
        logging.getLogger("abm").warning(
            "CLIP folder %s not found: grounding-cache keys name it by its path, so entries written where the "
            "folder exists are not found here", name_or_path)
        return name_or_path
    try:
        from huggingface_hub import try_to_load_from_cache

        cached = try_to_load_from_cache(name_or_path, "config.json")
    except Exception:  # noqa: BLE001 - an unusual hub cache only costs the revision in the key
        cached = None
    if isinstance(cached, str) and Path(cached).parent.parent.name == "snapshots":
        return f"{name_or_path}@{Path(cached).parent.name}"
    return name_or_path


@dataclass
class ClipBackbone:
    """A frozen CLIP model, its tokenizer and its image normalisation.

    Attributes:
        model: the :class:`transformers.CLIPModel` (eval mode, no gradients).
        tokenizer: a CLIP tokenizer (callable like a transformers tokenizer).
        name: the model's name (hub name, directory, or ``"random:<preset>:<seed>"``).
        device: where the model lives.
        dtype: parameter dtype (float32 on CPU; float16 recommended on CUDA).
        image_mean, image_std: per-channel RGB normalisation for pixel values in ``[0, 1]`` (3 values each;
            a local model's are read from its ``preprocessor_config.json``).
        fingerprint: what cache keys use (:func:`model_fingerprint`; ``""``: the name).
    """

    model: Any
    tokenizer: Any
    name: str
    device: torch.device
    dtype: torch.dtype = torch.float32
    image_mean: tuple[float, ...] = CLIP_MEAN
    image_std: tuple[float, ...] = CLIP_STD
    fingerprint: str = ""

    # ---- architecture facts -------------------------------------------------------------------
    @property
    def image_size(self) -> int:
        """Side in pixels of the square input the model was trained on (e.g. 336)."""
        return int(self.model.config.vision_config.image_size)

    @property
    def patch_size(self) -> int:
        return int(self.model.config.vision_config.patch_size)

    @property
    def grid_size(self) -> int:
        """Patches per side at :attr:`image_size` (e.g. 24 for ViT-L/14 at 336)."""
        return self.image_size // self.patch_size

    @property
    def embed_dim(self) -> int:
        """Dimension ``D`` of the joint image-text space."""
        return int(self.model.config.projection_dim)

    @property
    def text_width(self) -> int:
        """Width ``D_text`` of the text encoder's token embeddings."""
        return int(self.model.config.text_config.hidden_size)

    @property
    def logit_scale(self) -> float:
        """CLIP's learned softmax temperature ``exp(logit_scale)`` (100 for the OpenAI models)."""
        return float(self.model.logit_scale.detach().exp().item())

    # ---- images ---------------------------------------------------------------------------------
    def preprocess(self, images: ClipImages, input_size: tuple[int, int] | None = None) -> torch.Tensor:
        """Images -> normalised pixel values ``(B, 3, H_in, W_in)`` on :attr:`device`.

        Args:
            images: ``uint8`` array ``(B, H, W, 3)``, a sequence of ``uint8`` ``(H, W, 3)`` arrays (sizes may
                differ), or a float tensor ``(B, 3, H, W)`` in ``[0, 1]``.
            input_size: ``(H_in, W_in)`` the whole image is resized to (bicubic, no crop, so the patch grid
                covers the full image); default ``(image_size, image_size)``. Each side must be a multiple
                of the patch size; other sizes than the native one use interpolated position embeddings.
        """
        h_in, w_in = input_size or (self.image_size, self.image_size)
        if h_in % self.patch_size or w_in % self.patch_size:
            raise ConfigError(f"input_size {(h_in, w_in)} must be a multiple of the patch size {self.patch_size}")
        if isinstance(images, torch.Tensor):
            batch = [images[i] for i in range(images.shape[0])] if images.ndim == 4 else [images]
            tensors = [t.float() for t in batch]
        else:
            arrays = [images] if isinstance(images, np.ndarray) and images.ndim == 3 else list(images)
            tensors = []
            for i, a in enumerate(arrays):
                a = np.asarray(a)
                if a.ndim != 3 or a.shape[2] != 3:
                    raise ValueError(f"image {i} must be (H, W, 3), got shape {a.shape}")
                tensors.append(torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1).float() / 255.0)
        out = []
        for t in tensors:
            t = t.to(self.device)
            if t.shape[-2:] != (h_in, w_in):
                t = F.interpolate(t[None], size=(h_in, w_in), mode="bicubic", align_corners=False)[0]
            out.append(t.clamp(0.0, 1.0))
        pixels = torch.stack(out)
        mean = torch.tensor(self.image_mean, device=self.device).view(1, 3, 1, 1)
        std = torch.tensor(self.image_std, device=self.device).view(1, 3, 1, 1)
        return ((pixels - mean) / std).to(self.dtype)

    @torch.no_grad()
    def dense_features(self, images: ClipImages, input_size: tuple[int, int] | None = None,
                       mode: str = "maskclip") -> torch.Tensor:
        """Dense patch features ``(B, h, w, D)`` float32, unit length, for a batch of images.

        ``h = H_in / patch_size`` and ``w = W_in / patch_size`` (see :meth:`preprocess`); patch ``(i, j)``
        covers input rows ``[i p, (i + 1) p)`` and columns ``[j p, (j + 1) p)``. ``mode`` picks the last
        block (:data:`DENSE_MODES`, :func:`maskclip_head`); the default is MaskCLIP's value path.
        """
        pixels = self.preprocess(images, input_size)
        vision = self.model.vision_model
        native = pixels.shape[-2:] == (self.image_size, self.image_size)
        x = vision.embeddings(pixels, interpolate_pos_encoding=not native)
        x = vision.pre_layrnorm(x)
        for layer in vision.encoder.layers[:-1]:
            x = run_encoder_layer(layer, x)
        gh, gw = pixels.shape[-2] // self.patch_size, pixels.shape[-1] // self.patch_size
        x = F.normalize(maskclip_head(self.model, x, mode, (gh, gw)).float(), dim=-1)
        return x.reshape(x.shape[0], gh, gw, x.shape[-1])

    @torch.no_grad()
    def image_features(self, images: ClipImages, input_size: tuple[int, int] | None = None) -> torch.Tensor:
        """CLIP's image embedding ``(B, D)`` float32, unit length: the standard forward, CLS token, projection
        (what the contrastive loss trains; used to score object crops).

        The last layer is computed for the CLS token only (:func:`last_layer_cls`: its keys and values still see
        every token), and every product over the CLS rows runs row by row, so an image's embedding does not
        depend on the other images of the batch (the layers before it are products over ``B x tokens`` rows,
        which do not either): callers may memoise embeddings per image (:class:`~abm.grounding.grounders.
        ClipGrounder` does for its crops) and get what a fresh batch would give."""
        pixels = self.preprocess(images, input_size)
        vision = self.model.vision_model
        native = pixels.shape[-2:] == (self.image_size, self.image_size)
        x = vision.pre_layrnorm(vision.embeddings(pixels, interpolate_pos_encoding=not native))
        for layer in vision.encoder.layers[:-1]:
            x = run_encoder_layer(layer, x)
        cls = vision.post_layernorm(last_layer_cls(vision.encoder.layers[-1], x))
        return F.normalize(rowwise_linear(self.model.visual_projection, cls).float(), dim=-1)

    # ---- text -----------------------------------------------------------------------------------
    def tokenize(self, texts: Sequence[str], full_length: bool = True) -> dict[str, torch.Tensor]:
        """Token ids and attention mask ``(B, 77)``, padded / truncated to CLIP's context length, or
        ``(B, L)`` padded to the longest text only (``full_length=False``)."""
        if isinstance(texts, str):
            texts = [texts]
        enc = self.tokenizer(list(texts), padding="max_length" if full_length else "longest", max_length=TEXT_CONTEXT,
                             truncation=True, return_tensors="pt")
        return {"input_ids": enc["input_ids"].to(self.device),
                "attention_mask": enc["attention_mask"].to(self.device)}

    @torch.no_grad()
    def text_features(self, texts: Sequence[str]) -> torch.Tensor:
        """Projected, L2-normalised text features ``(B, D)`` float32.

        Texts are padded to the longest one, not to 77 tokens: CLIP's causal attention and end-of-text
        pooling make the padding irrelevant to the result, and a short prompt costs ~4x less.
        """
        out = self.model.text_model(**self.tokenize(texts, full_length=False))
        feats = self.model.text_projection(out.pooler_output)
        return F.normalize(feats.float(), dim=-1)

    @torch.no_grad()
    def text_tokens(self, texts: Sequence[str]) -> torch.Tensor:
        """Token embeddings ``(B, 77, D_text)`` float32 (text encoder output before the projection)."""
        out = self.model.text_model(**self.tokenize(texts))
        tokens: torch.Tensor = out.last_hidden_state.float()
        return tokens


QUICK_GELU_SCALE = 1.702
"""CLIP's ``quick_gelu(x) = x * sigmoid(1.702 x)``; equal to ``silu(1.702 x) / 1.702``."""


def sdpa_attention(attn: CLIPAttention, h: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, Any]:
    """A CLIP self-attention without masks over ``h`` ``(B, N, W)``: what the module computes with its ``sdpa``
    implementation (the same calls, so the same result), without the library's dispatch around them (a few
    percent of a small model's forward on the CPU). Other implementations, and calls that record gradients, run
    the module itself."""
    if torch.is_grad_enabled() or getattr(attn.config, "_attn_implementation", None) != "sdpa":
        out: tuple[torch.Tensor, Any] = attn(hidden_states=h)
        return out
    b, n, width = h.shape
    shape = (b, n, -1, attn.head_dim)
    q = attn.q_proj(h).view(shape).transpose(1, 2)
    k = attn.k_proj(h).view(shape).transpose(1, 2)
    v = attn.v_proj(h).view(shape).transpose(1, 2)
    mixed = F.scaled_dot_product_attention(q, k, v, dropout_p=0.0, scale=attn.scale, is_causal=False)
    projected: torch.Tensor = attn.out_proj(mixed.transpose(1, 2).reshape(b, n, width).contiguous())
    return projected


def run_encoder_layer(layer: CLIPEncoderLayer, x: torch.Tensor) -> torch.Tensor:
    """One CLIP encoder layer without masks, ``(B, N, W) -> (B, N, W)``: the layer's own attention and
    layer norms, and an MLP that computes ``quick_gelu`` as one ``silu`` kernel.

    ``fc2(quick_gelu(fc1 x)) = (W2 silu(1.702 (W1 x + b1))) / 1.702 + b2``; both scale factors ride on the
    matrix multiplications (``addmm``'s ``alpha``/``beta``), so the three elementwise passes of
    ``x * sigmoid(1.702 x)`` become one in-place ``silu``: ~10 % of a ViT-B/16 forward on a 2-core CPU,
    same result up to float rounding. Other activations, and any call that records gradients (training the
    benchmark CLIP), run the layer's own MLP out of place.
    """
    attn = sdpa_attention(layer.self_attn, layer.layer_norm1(x))
    x = x + (attn[0] if isinstance(attn, tuple) else attn)
    h = layer.layer_norm2(x)
    mlp = layer.mlp
    act = getattr(getattr(mlp, "config", None), "hidden_act", None)
    if act != "quick_gelu" or torch.is_grad_enabled():
        mixed: torch.Tensor = x + mlp(h)
        return mixed
    flat = h.reshape(-1, h.shape[-1])
    s = QUICK_GELU_SCALE
    hidden = torch.addmm(mlp.fc1.bias * s, flat, mlp.fc1.weight.t(), alpha=s)
    F.silu(hidden, inplace=True)
    out = torch.addmm(mlp.fc2.bias, hidden, mlp.fc2.weight.t(), alpha=1.0 / s)
    return x.add_(out.view_as(x))


def rowwise_linear(linear: torch.nn.Linear, x: torch.Tensor) -> torch.Tensor:
    """``linear`` on the rows of ``x`` ``(n, in)`` -> ``(n, out)``, each row as its own product.

    A matrix product over a few rows takes a different kernel path for each row count, so a row's result would
    change in the last bits with the number of rows beside it; one batched product of ``n`` single rows gives
    every row what it gets alone (the same function as ``linear(x)`` up to float rounding)."""
    n = x.shape[0]
    weight = linear.weight.t().unsqueeze(0).expand(n, -1, -1)
    rows = x.unsqueeze(1)
    bias: torch.Tensor | None = linear.bias  # None for the projections
    if bias is None:
        return torch.bmm(rows, weight)[:, 0]
    return torch.baddbmm(bias.view(1, 1, -1).expand(n, 1, -1), rows, weight)[:, 0]


def last_layer_cls(layer: CLIPEncoderLayer, x: torch.Tensor) -> torch.Tensor:
    """The output of a CLIP encoder layer at the CLS token only: ``(B, N, W)`` input -> ``(B, W)``.

    The CLS token's query attends over the keys and values of all ``N`` tokens; the query, output projection,
    residuals and MLP are computed for the CLS row alone (what the layer gives at that row, up to float
    rounding; the other ``N - 1`` rows of a last layer are never read by the image embedding). Products over
    the ``B`` CLS rows run row by row (:func:`rowwise_linear`)."""
    attn = layer.self_attn
    b, n, width = x.shape
    heads = attn.num_heads
    h = layer.layer_norm1(x)
    keys = attn.k_proj(h).view(b, n, heads, -1).transpose(1, 2)
    values = attn.v_proj(h).view(b, n, heads, -1).transpose(1, 2)
    query = rowwise_linear(attn.q_proj, h[:, 0]).view(b, heads, 1, -1)
    mixed = F.scaled_dot_product_attention(query, keys, values, scale=attn.scale)  # (B, heads, 1, head_dim)
    cls = x[:, 0] + rowwise_linear(attn.out_proj, mixed.reshape(b, width))
    mlp = layer.mlp
    hidden = mlp.activation_fn(rowwise_linear(mlp.fc1, layer.layer_norm2(cls)))
    return cls + rowwise_linear(mlp.fc2, hidden)


NACLIP_SIGMA = 5.0
"""Standard deviation of NACLIP's Gaussian window, in patches (the paper's value)."""


def gaussian_window(grid: tuple[int, int], sigma: float = NACLIP_SIGMA) -> torch.Tensor:
    """``(h*w, h*w)`` ``exp(-|p_i - p_j|^2 / (2 sigma^2))`` between the patch positions of a ``grid``."""
    rows, cols = torch.meshgrid(torch.arange(grid[0]), torch.arange(grid[1]), indexing="ij")
    pos = torch.stack([rows.reshape(-1), cols.reshape(-1)], dim=1).float()
    return torch.exp(-torch.cdist(pos, pos).pow(2) / (2.0 * sigma * sigma))


def last_block_attention(attn: CLIPAttention, h: torch.Tensor, mode: str, grid: tuple[int, int] | None = None,
                         sigma: float = NACLIP_SIGMA) -> torch.Tensor:
    """Attention weights ``(B, heads, N, N)`` of a :data:`DENSE_MODES` variant over the tokens ``h`` ``(B, N, W)``
    (the last block's layer-normed input, CLS first). ``naclip`` needs the patch ``grid`` (``N = 1 + h*w``);
    there, patches do not attend to the CLS token."""
    b, n, width = h.shape
    heads = attn.num_heads
    d = width // heads

    def split(t: torch.Tensor) -> torch.Tensor:
        return t.reshape(b, n, heads, d).transpose(1, 2)

    scale = d ** -0.5
    if mode == "clearclip":
        q = split(attn.q_proj(h))
        return torch.softmax(q @ q.transpose(-1, -2) * scale, dim=-1)
    if mode == "sclip":
        q, k = split(attn.q_proj(h)), split(attn.k_proj(h))
        return torch.softmax(q @ q.transpose(-1, -2) * scale, dim=-1) + \
            torch.softmax(k @ k.transpose(-1, -2) * scale, dim=-1)
    if mode == "naclip":
        if grid is None or grid[0] * grid[1] != n - 1:
            raise ValueError(f"naclip needs the patch grid of the {n - 1} patch tokens, got {grid}")
        k = split(attn.k_proj(h))
        bias = torch.zeros(n, n, dtype=h.dtype, device=h.device)
        bias[1:, 1:] = gaussian_window(grid, sigma).to(h)
        bias[1:, 0] = float("-inf")
        return torch.softmax(k @ k.transpose(-1, -2) * scale + bias, dim=-1)
    raise ValueError(f"dense mode must be one of {DENSE_MODES}, got {mode!r}")


def maskclip_head(model: Any, x: torch.Tensor, mode: str = "maskclip", grid: tuple[int, int] | None = None
                  ) -> torch.Tensor:
    """MaskCLIP's last block: ``(B, 1 + h*w, W)`` input of the last vision layer -> projected patch features
    ``(B, h*w, D)`` (not normalised): the value path only, no attention mixing, residual or MLP; CLS dropped.

    ``mode`` (:data:`DENSE_MODES`) mixes the values with a training-free attention first
    (:func:`last_block_attention`; ``grid`` = the patch grid, needed by ``naclip``); still no residual, no MLP.
    """
    vision = model.vision_model
    last = vision.encoder.layers[-1]
    h = last.layer_norm1(x)
    v = last.self_attn.v_proj(h)
    if mode != "maskclip":
        weights = last_block_attention(last.self_attn, h, mode, grid)
        b, n, width = v.shape
        heads = weights.shape[1]
        v = (weights @ v.reshape(b, n, heads, width // heads).transpose(1, 2)).transpose(1, 2).reshape(b, n, width)
    x = last.self_attn.out_proj(v)
    projected: torch.Tensor = model.visual_projection(vision.post_layernorm(x[:, 1:]))
    return projected


def _resolve_device(device: str | torch.device | None) -> torch.device:
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def _resolve_dtype(dtype: str | torch.dtype | None, device: torch.device) -> torch.dtype:
    if dtype is None:
        return torch.float16 if device.type == "cuda" else torch.float32
    if isinstance(dtype, str):
        return {"float32": torch.float32, "fp32": torch.float32, "float16": torch.float16,
                "fp16": torch.float16, "bfloat16": torch.bfloat16, "bf16": torch.bfloat16}[dtype]
    return dtype


def _finish(model: Any, device: torch.device, dtype: torch.dtype) -> Any:
    model = model.to(device=device, dtype=dtype).eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model


def build_config(preset: str = "tiny", vocab_size: int | None = None) -> Any:
    """A :class:`transformers.CLIPConfig` for one of :data:`CLIP_PRESETS`."""
    from transformers import CLIPConfig

    if preset not in CLIP_PRESETS:
        raise ValueError(f"unknown CLIP preset {preset!r}; choose from {sorted(CLIP_PRESETS)}")
    spec = CLIP_PRESETS[preset]
    text = dict(spec["text"], max_position_embeddings=TEXT_CONTEXT, projection_dim=spec["projection_dim"])
    if vocab_size is not None:
        # The offline tokenizer's ids: BOS = vocab_size - 2, EOS = PAD = vocab_size - 1.
        text.update(vocab_size=vocab_size, bos_token_id=vocab_size - 2, eos_token_id=vocab_size - 1,
                    pad_token_id=vocab_size - 1)
    vision = dict(spec["vision"], projection_dim=spec["projection_dim"])
    return CLIPConfig(text_config=text, vision_config=vision, projection_dim=spec["projection_dim"])


def random_clip(
    preset: str = "tiny",
    seed: int = 0,
    device: str | torch.device | None = "cpu",
    dtype: str | torch.dtype | None = None,
) -> ClipBackbone:
    """A randomly initialised CLIP of a preset architecture with the offline tokenizer.

    ``"tiny"`` (64 px, 8 px patches, D = 16) is for tests; ``"vit-b16"`` and ``"vit-l14-336"`` have the
    cost of the real models and are meant for speed measurements. Deterministic for a given seed.
    """
    from transformers import CLIPModel

    tokenizer = tiny_tokenizer()
    vocab_size = len(tokenizer)
    config = build_config(preset, vocab_size=vocab_size if preset == "tiny" else None)
    if preset != "tiny":
        config.text_config.vocab_size = max(config.text_config.vocab_size, vocab_size)
        config.text_config.eos_token_id = tokenizer.eos_token_id
        config.text_config.pad_token_id = tokenizer.pad_token_id
        config.text_config.bos_token_id = tokenizer.bos_token_id
    dev = _resolve_device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = CLIPModel(config)
    return ClipBackbone(_finish(model, dev, _resolve_dtype(dtype, dev)), tokenizer,
                        f"random:{preset}:{seed}", dev, _resolve_dtype(dtype, dev))


def tiny_clip(seed: int = 0, device: str | torch.device | None = "cpu") -> ClipBackbone:
    """The tiny random CLIP used by tests (same code path as the real models)."""
    return random_clip("tiny", seed=seed, device=device, dtype=torch.float32)


def _image_stats(folder: Path) -> tuple[tuple[float, ...], tuple[float, ...]]:
    cfg = folder / "preprocessor_config.json"
    if cfg.is_file():
        data = json.loads(cfg.read_text(encoding="utf-8"))
        if "image_mean" in data and "image_std" in data:
            return tuple(float(v) for v in data["image_mean"]), tuple(float(v) for v in data["image_std"])
    return CLIP_MEAN, CLIP_STD


@contextlib.contextmanager
def _quiet_transformers() -> Iterator[None]:
    """transformers' progress bars off (its "Loading weights" bar), as they were afterwards."""
    from transformers.utils import logging as hf_logging

    was = hf_logging.is_progress_bar_enabled()
    hf_logging.disable_progress_bar()  # type: ignore[no-untyped-call]
    try:
        yield
    finally:
        if was:
            hf_logging.enable_progress_bar()  # type: ignore[no-untyped-call]


def load_clip(
    name_or_path: str = DEFAULT_MODEL,
    device: str | torch.device | None = None,
    dtype: str | torch.dtype | None = None,
    allow_download: bool = False,
    seed: int = 0,
) -> ClipBackbone:
    """Load a CLIP backbone.

    Args:
        name_or_path: a hub name (found in the local Hugging Face cache, ``$HF_HOME``), a local directory
            written by ``save_pretrained``, ``"tiny"`` or ``"random:<preset>"`` (random weights, see
            :func:`random_clip`).
        device: ``"cpu"``, ``"cuda"``...; default CUDA when available.
        dtype: parameter dtype; default float16 on CUDA, float32 on CPU.
        allow_download: also try the network when the weights are not cached (off by default, also
            forced off by ``HF_HUB_OFFLINE=1``).

    Raises:
        ClipWeightsNotFoundError: the weights are not available (the message says how to provide them).
    """
    if name_or_path == "tiny" or name_or_path.startswith("random:"):
        logging.getLogger("abm").warning("CLIP %s: %s", name_or_path, TEST_ONLY_CLIP)
    if name_or_path == "tiny":
        return tiny_clip(seed=seed, device=device or "cpu")
    if name_or_path.startswith("random:"):
        return random_clip(name_or_path.split(":", 1)[1], seed=seed, device=device, dtype=dtype)
    from transformers import CLIPModel, CLIPTokenizer

    dev = _resolve_device(device)
    dt = _resolve_dtype(dtype, dev)
    offline = os.environ.get("HF_HUB_OFFLINE", "0") not in ("", "0") or \
        os.environ.get("TRANSFORMERS_OFFLINE", "0") not in ("", "0")
    local_only = not allow_download or offline
    if _is_local_path(name_or_path):
        folder = Path(name_or_path).expanduser()
        if not (folder / "config.json").is_file():
            raise ClipWeightsNotFoundError(_missing_weights_message(
                name_or_path, f"no directory with a config.json at {folder}"))
        source, mean_std = str(folder), _image_stats(folder)
    else:
        source, mean_std = name_or_path, (CLIP_MEAN, CLIP_STD)
    try:
        with _quiet_transformers():  # no "Loading weights" progress bar in the commands' logs
            model = CLIPModel.from_pretrained(source, local_files_only=local_only)
            tokenizer = CLIPTokenizer.from_pretrained(source, local_files_only=local_only)
    except OSError as err:
        reason = "not in the local cache, downloads disabled" if local_only else f"download failed: {err}"
        raise ClipWeightsNotFoundError(_missing_weights_message(name_or_path, reason)) from err
    return ClipBackbone(_finish(model, dev, dt), tokenizer, name_or_path, dev, dt, *mean_std,
                        fingerprint=model_fingerprint(name_or_path))


def load_clip_model(config: ClipModelConfig) -> ClipBackbone:
    """The backbone a :class:`~abm.grounding.config.ClipModelConfig` names (:func:`load_clip`): the CLIP grounder's
    and the CLIP text encoder's."""
    return load_clip(config.model or DEFAULT_MODEL, device=config.device, allow_download=config.allow_download)
