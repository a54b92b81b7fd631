"""Train a small CLIP from scratch on simulator renders (``abm clip train``), for real grounding numbers.

Model: a transformers :class:`~transformers.CLIPModel` (:func:`bench_clip_config`: ViT with 8 px patches
at 128 px input, so a 128 px benchmark camera image gives a 16 x 16 MaskCLIP grid) with the project's
offline character-level tokenizer (:mod:`abm.grounding.tokenizer`).

Loss = contrastive + ``dense_weight`` x dense:

* **contrastive** (CLIP's symmetric InfoNCE) between the CLS image embedding of every crop
  (object or background) and its caption; captions of the same class are all positives (soft targets), so
  two crops of the ketchup in one batch are not pushed apart;
* **dense**: the MaskCLIP patch features the grounder uses (:meth:`abm.grounding.clip.ClipBackbone.dense_features`:
  value path of the last block, no attention mixing, residual or MLP) of every image (scenes and crops)
  are classified against the text features of the mask-field prompts of all classes plus the generic
  negatives ("a photo of an object", "... things", "... stuff", "... texture"). A patch's label is the
  object covering at least ``object_fraction`` of it (the largest one), else the background class covering
  most of it; the target puts ``1 - parent_weight`` on the label and ``parent_weight`` on its generic
  phrase (:data:`abm.clip_training.captions.GENERIC_PARENT`), so "an object" is the best match after
  the object's own name and the softmax-vs-negatives normalisation means something.

The run is resumable (``checkpoint.pt`` every ``checkpoint_every`` steps: weights, optimiser, data order,
RNG). The result is a standard transformers folder (``config.json``, ``model.safetensors``, tokenizer
files, ``preprocessor_config.json`` with the image mean/std) that :func:`abm.grounding.clip.load_clip`
loads, plus ``abm_clip.json`` (recipe, data, timings, final losses) and ``train_log.csv``.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from abm.clip_training.captions import GENERIC_PARENT, OBJECT_PARENT, class_prompts
from abm.clip_training.data import OBJECT_CROP, SCENE, ClipDataset
from abm.errors import CheckpointError, OutputError
from abm.files import atomic_path, load_torch_data, write_text_atomic
from abm.grounding.clip import TEXT_CONTEXT, maskclip_head, run_encoder_layer
from abm.grounding.config import DEFAULT_NEGATIVES
from abm.grounding.tokenizer import char_vocab, tiny_tokenizer
from abm.language.instruction import clip_prompt
from abm.progress import Progress

log = logging.getLogger("abm")

CHECKPOINT = "checkpoint.pt"
SUMMARY = "abm_clip.json"
LOG_CSV = "train_log.csv"

# The default architecture (1.8 M parameters): ~45 images/s of training on 2 idle CPU cores.
BENCH_ARCH: dict[str, Any] = dict(
    projection_dim=128,
    vision=dict(hidden_size=128, intermediate_size=512, num_hidden_layers=4, num_attention_heads=2,
                image_size=128, patch_size=8),
    text=dict(hidden_size=128, intermediate_size=512, num_hidden_layers=4, num_attention_heads=2),
)


@dataclass
class ClipTrainConfig:
    """Recipe of one training run.

    Attributes:
        steps: optimiser steps.
        max_minutes: optional training time budget (minutes of training, resumes included): training stops
            when it is spent, and the learning-rate schedule follows whichever of steps and time runs out
            first, so a slow (shared) machine still ends with a fully decayed learning rate.
        batch_size: images per step (scenes and crops together).
        lr: peak learning rate of AdamW (linear warm-up over ``warmup_steps``, cosine decay to 0).
        weight_decay: AdamW weight decay on matrices (not on biases, norms, embeddings).
        warmup_steps: linear warm-up steps.
        dense_weight: weight of the dense (patch) loss.
        parent_weight: target probability of a patch's generic phrase in the dense loss.
        object_fraction: fraction of a patch an object must cover to be its label.
        seed: data order, augmentation and initialisation seed.
        threads: ``torch.set_num_threads``.
        checkpoint_every: steps between checkpoints.
        log_every: steps between log lines / CSV rows.
        arch: model architecture (see :data:`BENCH_ARCH`).
    """

    steps: int = 1600
    max_minutes: float | None = None
    batch_size: int = 48
    lr: float = 5e-4
    weight_decay: float = 0.05
    warmup_steps: int = 150
    dense_weight: float = 1.0
    parent_weight: float = 0.1
    object_fraction: float = 0.2
    seed: int = 0
    threads: int = 2
    checkpoint_every: int = 100
    log_every: int = 25
    arch: dict[str, Any] | None = None

    def architecture(self) -> dict[str, Any]:
        return self.arch or BENCH_ARCH


def bench_clip_config(arch: dict[str, Any], vocab_size: int) -> Any:
    """A :class:`transformers.CLIPConfig` for ``arch`` with the offline tokenizer's ids.

    The offline tokenizer has ``vocab_size`` ids; BOS = ``vocab_size - 2``, EOS = PAD = ``vocab_size - 1``
    (the text model pools at the first EOS).
    """
    from transformers import CLIPConfig

    proj = int(arch["projection_dim"])
    text = dict(arch["text"], max_position_embeddings=TEXT_CONTEXT, projection_dim=proj, vocab_size=vocab_size,
                bos_token_id=vocab_size - 2, eos_token_id=vocab_size - 1, pad_token_id=vocab_size - 1)
    vision = dict(arch["vision"], projection_dim=proj)
    return CLIPConfig(text_config=text, vision_config=vision, projection_dim=proj)


# --------------------------------------------------------------------------------------------------
# Forward passes with gradients
# --------------------------------------------------------------------------------------------------
def encode_images(model: Any, pixels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(image embeddings (B, D), MaskCLIP patch features (B, h*w, D))``, both L2-normalised.

    The image embedding is CLIP's (CLS token after the last block, ``post_layernorm``, projection); the
    patch features follow :meth:`abm.grounding.clip.ClipBackbone.dense_features` exactly, sharing every
    block but the last with the CLS path. ``pixels``: normalised ``(B, 3, S, S)`` at the native size.
    """
    vision = model.vision_model
    x = vision.pre_layrnorm(vision.embeddings(pixels))
    layers = vision.encoder.layers
    for layer in layers[:-1]:
        x = run_encoder_layer(layer, x)
    dense = maskclip_head(model, x)
    cls = model.visual_projection(vision.post_layernorm(run_encoder_layer(layers[-1], x)[:, 0]))
    return F.normalize(cls, dim=-1), F.normalize(dense, dim=-1)


def encode_texts(model: Any, tokenizer: Any, texts: Sequence[str]) -> torch.Tensor:
    """Projected, L2-normalised text features ``(T, D)`` (padded to the longest text)."""
    enc = tokenizer(list(texts), padding="longest", max_length=77, truncation=True, return_tensors="pt")
    out = model.text_model(input_ids=enc["input_ids"], attention_mask=enc["attention_mask"])
    return F.normalize(model.text_projection(out.pooler_output), dim=-1)


# --------------------------------------------------------------------------------------------------
# Targets and losses
# --------------------------------------------------------------------------------------------------
def patch_labels(classes: torch.Tensor, patch: int, num_classes: int, num_objects: int,
                 object_fraction: float = 0.2, background_fraction: float = 0.5) -> torch.Tensor:
    """Class label of every patch, ``(B, h*w)`` int64, -1 where ambiguous.

    Args:
        classes: ``(B, S, S)`` uint8/int class index per pixel; indices ``< num_objects`` are objects,
            ``num_objects .. num_classes - 1`` background classes, others ignored.
        patch: patch side in pixels (``S`` must be a multiple).
        object_fraction: an object covering at least this fraction of a patch labels it (the largest one
            wins), so small objects still own the patch they sit in.
        background_fraction: otherwise the largest background class must cover this fraction.
    """
    b, s, _ = classes.shape
    g = s // patch
    c = classes.long().clamp(max=num_classes).reshape(b, g, patch, g, patch).permute(0, 1, 3, 2, 4)
    c = c.reshape(b * g * g, patch * patch)
    counts = torch.zeros(b * g * g, num_classes + 1).scatter_add_(1, c, torch.ones_like(c, dtype=torch.float32))
    frac = counts[:, :num_classes] / float(patch * patch)
    obj_frac, obj = frac[:, :num_objects].max(1)
    bg_frac, bg = frac[:, num_objects:].max(1)
    label = torch.where(bg_frac >= background_fraction, bg + num_objects, torch.full_like(bg, -1))
    label = torch.where(obj_frac >= object_fraction, obj, label)
    return label.reshape(b, g * g)


def dense_vocabulary(class_names: Sequence[str], num_objects: int) -> tuple[list[str], list[int]]:
    """Prompts of the dense loss (class prompts, then the generic negatives) and each class's parent index."""
    prompts = class_prompts(class_names) + [clip_prompt(n) for n in DEFAULT_NEGATIVES]
    generic = {n: len(class_names) + i for i, n in enumerate(DEFAULT_NEGATIVES)}
    parents = [generic[OBJECT_PARENT] if i < num_objects else generic[GENERIC_PARENT[c]]
               for i, c in enumerate(class_names)]
    return prompts, parents


def dense_loss(patch_feats: torch.Tensor, labels: torch.Tensor, vocab: torch.Tensor, parents: torch.Tensor,
               scale: torch.Tensor, parent_weight: float) -> torch.Tensor:
    """Soft cross-entropy of patch features ``(B, N, D)`` against the vocabulary ``(V, D)``.

    ``labels`` ``(B, N)`` (-1 = ignored); the target is ``1 - parent_weight`` on the label and
    ``parent_weight`` on ``parents[label]``.
    """
    keep = labels >= 0
    if not keep.any():
        return patch_feats.sum() * 0.0
    feats, lab = patch_feats[keep], labels[keep]
    logp = F.log_softmax(scale * feats @ vocab.T, dim=-1)
    return -((1 - parent_weight) * logp.gather(1, lab[:, None]).squeeze(1)
             + parent_weight * logp.gather(1, parents[lab][:, None]).squeeze(1)).mean()


def contrastive_loss(image: torch.Tensor, text: torch.Tensor, labels: torch.Tensor,
                     scale: torch.Tensor) -> torch.Tensor:
    """Symmetric CLIP loss with every same-class pair positive: ``image, text (n, D)``, ``labels (n,)``."""
    logits = scale * image @ text.T
    same = (labels[:, None] == labels[None, :]).float()
    target = same / same.sum(1, keepdim=True)
    return 0.5 * (-(target * F.log_softmax(logits, 1)).sum(1).mean()
                  - (target * F.log_softmax(logits.T, 1)).sum(1).mean())


# --------------------------------------------------------------------------------------------------
# Batches
# --------------------------------------------------------------------------------------------------
def image_stats(images: np.ndarray, limit: int = 2000) -> tuple[list[float], list[float]]:
    """Per-channel mean and std of ``uint8`` images ``(N, S, S, 3)`` in ``[0, 1]`` (first ``limit``)."""
    x = images[:limit].reshape(-1, 3).astype(np.float64) / 255.0
    return x.mean(0).round(6).tolist(), x.std(0).round(6).tolist()


def make_batch(data: ClipDataset, idx: np.ndarray, mean: Sequence[float], std: Sequence[float],
               rng: np.random.Generator | None) -> dict[str, Any]:
    """Tensors of samples ``idx``: normalised pixels ``(B, 3, S, S)``, classes ``(B, S, S)``, crop info.

    With ``rng``: random horizontal flips and brightness / contrast jitter (same flip for the class map).
    """
    images = torch.from_numpy(data.images[idx]).permute(0, 3, 1, 2).float() / 255.0
    classes = torch.from_numpy(data.classes[idx].astype(np.int64))
    if rng is not None:
        flip = torch.from_numpy(rng.random(len(idx)) < 0.5)
        images[flip] = images[flip].flip(-1)
        classes[flip] = classes[flip].flip(-1)
        gain = torch.from_numpy(rng.uniform(0.8, 1.2, (len(idx), 1, 1, 1))).float()
        contrast = torch.from_numpy(rng.uniform(0.8, 1.2, (len(idx), 1, 1, 1))).float()
        mu = images.mean((1, 2, 3), keepdim=True)
        images = ((images - mu) * contrast + mu * gain).clamp(0, 1)
    m = torch.tensor(mean).view(1, 3, 1, 1)
    s = torch.tensor(std).view(1, 3, 1, 1)
    crops = data.kind[idx] != SCENE
    return {"pixels": (images - m) / s, "classes": classes, "crop": torch.from_numpy(crops),
            "label": torch.from_numpy(data.label[idx].astype(np.int64)),
            "caption": [str(c) for c in data.caption[idx]]}


class BatchOrder:
    """Epoch-wise random order over a dataset; its state is ``(epoch, position)`` (resumable)."""

    def __init__(self, size: int, batch: int, seed: int, epoch: int = 0, position: int = 0) -> None:
        self.size, self.batch, self.seed = size, batch, seed
        self.epoch, self.position = epoch, position
        self._perm = np.random.default_rng([seed, epoch]).permutation(size)

    def next(self) -> np.ndarray:
        if self.position + self.batch > self.size:
            self.epoch, self.position = self.epoch + 1, 0
            self._perm = np.random.default_rng([self.seed, self.epoch]).permutation(self.size)
        idx = self._perm[self.position:self.position + self.batch]
        self.position += self.batch
        return np.sort(idx)

    def state(self) -> dict[str, int]:
        return {"epoch": self.epoch, "position": self.position}


def run_fraction(step: int, elapsed_s: float, config: ClipTrainConfig) -> float:
    """Fraction of the run done: steps, or time when ``max_minutes`` is set and runs out first."""
    done = step / config.steps
    if config.max_minutes:
        done = max(done, elapsed_s / (60.0 * config.max_minutes))
    return min(1.0, done)


def lr_at(step: int, config: ClipTrainConfig, elapsed_s: float = 0.0) -> float:
    """Learning rate at ``step``: linear warm-up over ``warmup_steps``, then cosine decay to 0 at the end
    of the run (:func:`run_fraction`)."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    start = config.warmup_steps / config.steps
    t = (run_fraction(step, elapsed_s, config) - start) / max(1e-9, 1.0 - start)
    return config.lr * 0.5 * (1 + math.cos(math.pi * min(1.0, max(0.0, t))))


# --------------------------------------------------------------------------------------------------
# The trainer
# --------------------------------------------------------------------------------------------------
def new_model(config: ClipTrainConfig) -> tuple[Any, Any]:
    """A freshly initialised ``(CLIPModel, tokenizer)`` (seeded)."""
    from transformers import CLIPModel

    tokenizer = tiny_tokenizer()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = CLIPModel(bench_clip_config(config.architecture(), len(tokenizer)))
    return model, tokenizer


def _optimizer(model: Any, config: ClipTrainConfig) -> torch.optim.Optimizer:
    decay = [p for n, p in model.named_parameters() if p.ndim >= 2 and "embedding" not in n]
    other = [p for n, p in model.named_parameters() if not (p.ndim >= 2 and "embedding" not in n)]
    return torch.optim.AdamW([{"params": decay, "weight_decay": config.weight_decay},
                              {"params": other, "weight_decay": 0.0}], lr=config.lr, betas=(0.9, 0.98), eps=1e-6)


def train_step(model: Any, tokenizer: Any, batch: dict[str, Any], vocab_prompts: Sequence[str],
               parents: torch.Tensor, num_objects: int, config: ClipTrainConfig) -> dict[str, torch.Tensor]:
    """Losses of one batch (``loss`` = contrastive + dense_weight x dense), with the graph for backward."""
    patch = int(model.config.vision_config.patch_size)
    scale = model.logit_scale.exp().clamp(max=100.0)
    image, dense = encode_images(model, batch["pixels"])
    vocab = encode_texts(model, tokenizer, vocab_prompts)
    labels = patch_labels(batch["classes"], patch, len(parents), num_objects, config.object_fraction)
    l_dense = dense_loss(dense, labels, vocab, parents, scale, config.parent_weight)
    crop = batch["crop"]
    if int(crop.sum()) >= 2:
        texts = encode_texts(model, tokenizer, [c for c, k in zip(batch["caption"], crop.tolist(), strict=True) if k])
        l_con = contrastive_loss(image[crop], texts, batch["label"][crop], scale)
    else:
        l_con = image.sum() * 0.0
    return {"loss": l_con + config.dense_weight * l_dense, "contrastive": l_con, "dense": l_dense}


def save_model(model: Any, tokenizer: Any, out: Path, mean: Sequence[float], std: Sequence[float]) -> None:
    """Write the transformers folder :func:`abm.grounding.clip.load_clip` reads."""
    out.mkdir(parents=True, exist_ok=True)
    model.save_pretrained(out)
    tokenizer.save_pretrained(out)
    # The slow tokenizer's files too, so older transformers versions load the folder as well.
    (out / "vocab.json").write_text(json.dumps(char_vocab()), encoding="utf-8")
    (out / "merges.txt").write_text("#version: 0.2\n", encoding="utf-8")
    size = int(model.config.vision_config.image_size)
    pre = {"image_processor_type": "CLIPImageProcessor", "image_mean": list(mean), "image_std": list(std),
           "do_resize": True, "size": {"shortest_edge": size}, "do_center_crop": True,
           "crop_size": {"height": size, "width": size}, "do_normalize": True, "do_rescale": True,
           "rescale_factor": 1 / 255, "resample": 3}
    (out / "preprocessor_config.json").write_text(json.dumps(pre, indent=2) + "\n", encoding="utf-8")


def load_training_state(path: str | Path) -> dict[str, Any]:
    """The resumable state in ``checkpoint.pt``, read with ``weights_only=True`` (tensors and plain data only,
    so a crafted file is refused instead of running its code).

    Raises:
        DataError: the file holds other Python objects, or cannot be read (a CheckpointError: or lacks the
            training state).
    """
    state = load_torch_data(path, "abm CLIP training checkpoint")
    missing = [k for k in ("model", "optimizer", "step", "elapsed", "history", "order", "rng", "torch_rng", "mean",
                           "std") if not isinstance(state, dict) or k not in state]
    if missing:
        raise CheckpointError(f"{path} is not an abm CLIP training checkpoint (missing {', '.join(missing)}); "
                              "train into a new --out folder")
    checked: dict[str, Any] = state
    return checked


def train(data: ClipDataset, out: str | Path, config: ClipTrainConfig | None = None, resume: bool = False,
          progress: bool = True, extra_summary: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train on ``data`` and write the model folder ``out``; returns the summary written to ``abm_clip.json``.

    Raises:
        OutputError: ``out`` holds a checkpoint and ``resume`` is False.
    """
    config = config or ClipTrainConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    ckpt_path = out / CHECKPOINT
    if ckpt_path.is_file() and not resume:
        raise OutputError(f"{ckpt_path} exists: pass --resume to continue that run, or use another --out")
    model, tokenizer = new_model(config)
    model.train()
    optimizer = _optimizer(model, config)
    num_objects = len(data.class_names) - 3
    vocab_prompts, parent_list = dense_vocabulary(data.class_names, num_objects)
    parents = torch.tensor(parent_list)
    mean, std = image_stats(data.images)
    order = BatchOrder(len(data), config.batch_size, config.seed)
    rng = np.random.default_rng([config.seed, 1])
    step, elapsed, history = 0, 0.0, []
    if resume and ckpt_path.is_file():
        state = load_training_state(ckpt_path)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step, elapsed, history = state["step"], state["elapsed"], state["history"]
        order = BatchOrder(len(data), config.batch_size, config.seed, **state["order"])
        rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        mean, std = state["mean"], state["std"]
        log.info("resumed %s at step %d (%.0f s trained)", out, step, elapsed)
    csv_file = (out / LOG_CSV).open("a", newline="", encoding="utf-8")
    writer = csv.writer(csv_file)
    if csv_file.tell() == 0:
        writer.writerow(["step", "loss", "contrastive", "dense", "lr", "logit_scale", "elapsed_s", "images_per_s"])

    def checkpoint() -> None:
        with atomic_path(ckpt_path) as tmp, tmp.open("wb") as fh:
            torch.save({"model": model.state_dict(), "optimizer": optimizer.state_dict(), "step": step,
                        "elapsed": elapsed, "history": history, "order": order.state(),
                        "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(), "mean": mean, "std": std,
                        "config": asdict(config)}, fh)

    bar = Progress(config.steps, "clip train", "steps", initial=step, bar=progress)
    running: dict[str, float] = {}
    window_start, window_images = time.perf_counter(), 0
    try:
        while run_fraction(step, elapsed, config) < 1.0:
            t0 = time.perf_counter()
            lr = lr_at(step, config, elapsed)
            for group in optimizer.param_groups:
                group["lr"] = lr
            batch = make_batch(data, order.next(), mean, std, rng)
            losses = train_step(model, tokenizer, batch, vocab_prompts, parents, num_objects, config)
            optimizer.zero_grad(set_to_none=True)
            losses["loss"].backward()  # type: ignore[no-untyped-call]  # torch's Tensor.backward is unannotated
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            optimizer.step()
            with torch.no_grad():
                model.logit_scale.clamp_(0, math.log(100.0))
            step += 1
            elapsed += time.perf_counter() - t0
            window_images += config.batch_size
            for k, v in losses.items():
                running[k] = running.get(k, 0.0) + float(v.detach())
            bar.update(1)
            last = run_fraction(step, elapsed, config) >= 1.0
            if step % config.log_every == 0 or last:
                n = config.log_every if step % config.log_every == 0 else step % config.log_every
                avg = {k: v / n for k, v in running.items()}
                speed = window_images / max(1e-9, time.perf_counter() - window_start)
                row = {"step": step, **{k: round(v, 4) for k, v in avg.items()}, "lr": lr,
                       "logit_scale": round(float(model.logit_scale.detach().exp()), 2), "elapsed_s": round(elapsed, 1),
                       "images_per_s": round(speed, 1)}
                history.append(row)
                writer.writerow([row[k] for k in ("step", "loss", "contrastive", "dense", "lr", "logit_scale",
                                                  "elapsed_s", "images_per_s")])
                csv_file.flush()
                bar.postfix.update(loss=f"{avg['loss']:.3f}", con=f"{avg['contrastive']:.3f}",
                                   dense=f"{avg['dense']:.3f}", ips=f"{speed:.1f}")
                running, window_start, window_images = {}, time.perf_counter(), 0
            if step % config.checkpoint_every == 0 or last:
                checkpoint()
    finally:
        bar.close()
        csv_file.close()
    model.eval()
    save_model(model, tokenizer, out, mean, std)
    summary = {
        "recipe": asdict(config) | {"arch": config.architecture()},
        "parameters": int(sum(p.numel() for p in model.parameters())),
        "steps": step, "train_seconds": round(elapsed, 1),
        "final": history[-1] if history else None,
        "first": history[0] if history else None,
        "classes": list(data.class_names), "samples": len(data),
        "image_mean": mean, "image_std": std,
        **(extra_summary or {}),
    }
    write_text_atomic(out / SUMMARY, json.dumps(summary, indent=2) + "\n")
    return summary


# --------------------------------------------------------------------------------------------------
# Evaluation helpers (zero-shot classification)
# --------------------------------------------------------------------------------------------------
@torch.no_grad()
def zero_shot_accuracy(backbone: Any, data: ClipDataset, classes: Sequence[str] | None = None,
                       batch: int = 64) -> dict[str, Any]:
    """Top-1 zero-shot classification of the object crops of ``data`` with a :class:`ClipBackbone`.

    Every crop's CLS image embedding is compared with ``"a photo of a X"`` for every object class X
    (default: all object classes of ``data``); also reports the accuracy of the mean MaskCLIP patch
    feature over the object's pixels (the dense features the grounder uses). Returns overall and
    per-class accuracies.
    """
    names = list(classes or data.class_names[:len(data.class_names) - 3])
    text = backbone.text_features(class_prompts(names)).cpu()
    lookup = {n: i for i, n in enumerate(names)}
    idx = np.nonzero(data.kind == OBJECT_CROP)[0]
    idx = np.array([i for i in idx if data.class_names[data.label[i]] in lookup], dtype=np.int64)
    correct_cls, correct_dense, truth = [], [], []
    model = backbone.model
    for start in range(0, len(idx), batch):
        part = idx[start:start + batch]
        pixels = backbone.preprocess(data.images[part])
        image, _ = encode_images(model, pixels)
        dense = backbone.dense_features(data.images[part]).cpu()          # (b, g, g, D)
        g = dense.shape[1]
        want = torch.tensor([lookup[data.class_names[data.label[i]]] for i in part])
        pred_cls = (image.float().cpu() @ text.T).argmax(1)
        masks = torch.from_numpy(data.classes[part].astype(np.int64) == data.label[part][:, None, None])
        masks = F.adaptive_avg_pool2d(masks.float()[:, None], (g, g))[:, 0]  # object share of each patch
        pooled = F.normalize((dense * masks[..., None]).sum((1, 2)), dim=-1)
        pred_dense = (pooled @ text.T).argmax(1)
        correct_cls += (pred_cls == want).tolist()
        correct_dense += (pred_dense == want).tolist()
        truth += want.tolist()
    truth_arr = np.array(truth)
    per_class = {n: float(np.mean(np.array(correct_cls)[truth_arr == i])) for i, n in enumerate(names)
                 if (truth_arr == i).any()}
    return {"crops": len(truth), "classes": len(names), "accuracy": float(np.mean(correct_cls)) if truth else math.nan,
            "dense_accuracy": float(np.mean(correct_dense)) if truth else math.nan, "per_class": per_class}
