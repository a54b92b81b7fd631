"""Grounders: observation + point cloud + target description -> :class:`MaskField`.

All grounders share one call::

    field = grounder.ground(observation, cloud, target, object_names)

* :class:`ClipGrounder` — the method: CLIP Feature Cloud + text prompt -> normalised heatmap -> mask.
* :class:`~abm.grounding.tracking.TrackingGrounder` — grounds once with another grounder, then tracks
  the target's 3-D points from step to step.
* :class:`OracleGrounder` — simulator segmentation + object names: the points whose segmentation id is
  named ``target``. An upper bound, and the default where real CLIP weights are unavailable.

Build them with :func:`make_grounder`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch

from abm.geometry import PointCloud
from abm.grounding.cache import GroundingCache, cloud_key, content_key, image_key
from abm.grounding.instruction import clip_prompt
from abm.grounding.mask_field import MaskField, MaskFieldConfig, mask_field_from_features, negative_prompts
from abm.types import Observation

GROUNDERS: tuple[str, ...] = ("oracle", "clip", "tracking")


@runtime_checkable
class Grounder(Protocol):
    """The interface the policy, training and evaluation code call."""

    name: str

    def ground(
        self,
        observation: Observation,
        cloud: PointCloud,
        target: str,
        object_names: Mapping[int, str] | None = None,
    ) -> MaskField:
        """Mask field over the points of ``cloud`` (a fused cloud of ``observation``) for ``target``."""
        ...


def normalize_name(name: str) -> str:
    """Canonical form for comparing object names: lower case, ``_``/``-`` as spaces, no articles."""
    words = re.sub(r"[_\-]+", " ", str(name).lower()).split()
    return " ".join(w for w in words if w not in ("a", "an", "the"))


def match_object_ids(target: str, object_names: Mapping[int, str]) -> list[int]:
    """Segmentation ids whose name is ``target``.

    Names are compared in :func:`normalize_name` form. If no name is equal, names that contain the
    target as whole words (``"mug"`` -> ``"red mug"``) are used, but only when exactly one object matches,
    so an ambiguous description never silently grounds several objects.
    """
    want = normalize_name(target)
    names = {int(i): normalize_name(n) for i, n in object_names.items()}
    exact = [i for i, n in names.items() if n == want]
    if exact:
        return exact
    pattern = re.compile(rf"(^| ){re.escape(want)}( |$)")
    partial = [i for i, n in names.items() if want and pattern.search(n)]
    return partial if len(partial) == 1 else []


def segmentation_of_points(observation: Observation, cloud: PointCloud) -> np.ndarray:
    """``(N,)`` int32 segmentation id of every point (needs simulator segmentation in every camera)."""
    missing = [n for n in cloud.camera_names if observation.camera(n).segmentation is None]
    if missing:
        raise ValueError(f"cameras {missing} have no segmentation; the oracle grounder needs simulator "
                         "segmentation (use the clip grounder on real data)")
    return cloud.gather({n: observation.camera(n).segmentation for n in cloud.camera_names})


def target_point_mask(
    observation: Observation, cloud: PointCloud, target: str, object_names: Mapping[int, str]
) -> np.ndarray:
    """``(N,)`` bool ground-truth points of ``target`` (segmentation id named ``target``)."""
    ids = match_object_ids(target, object_names)
    seg = segmentation_of_points(observation, cloud)
    return np.isin(seg, ids) if ids else np.zeros(len(cloud), bool)


def _check_cloud(observation: Observation, cloud: PointCloud) -> None:
    if not isinstance(cloud, PointCloud):
        raise TypeError(f"cloud must be an abm.geometry.PointCloud, got {type(cloud).__name__}")
    missing = [n for n in cloud.camera_names if n not in observation.cameras]
    if missing:
        raise KeyError(f"cloud uses cameras {missing} that the observation lacks; "
                       f"available: {sorted(observation.cameras)}")


class OracleGrounder:
    """Ground truth from simulator segmentation: mask = points whose object is named ``target``.

    ``heatmap`` equals ``mask``; ``found`` is False when no object has that name or none of its points
    is in the cloud (the mask is then empty).
    """

    name = "oracle"

    def ground(
        self,
        observation: Observation,
        cloud: PointCloud,
        target: str,
        object_names: Mapping[int, str] | None = None,
    ) -> MaskField:
        _check_cloud(observation, cloud)
        if not object_names:
            raise ValueError("the oracle grounder needs the episode's object_names (segmentation id -> name)")
        mask = target_point_mask(observation, cloud, target, object_names).astype(np.float32)
        return MaskField(mask, mask.copy(), bool(mask.any()), target, "")


class ClipGrounder:
    """The ABM grounder: MaskCLIP feature cloud, prompt ``"a photo of a X"``, normalised heatmap, threshold.

    Args:
        backbone: a ready :class:`~abm.grounding.clip.ClipBackbone`; else one is loaded from ``model``.
        model: hub name, local directory, ``"tiny"`` or ``"random:<preset>"`` (see :func:`load_clip`).
        device: torch device for the backbone (default CUDA when available).
        config: normalisation / threshold settings (:class:`MaskFieldConfig`).
        cache: a :class:`GroundingCache`, a directory for one, or None for a memory-only cache.
        input_size: ``(H, W)`` the camera images are resized to (default the model's native size).
        cache_features: also keep per-image patch features in the cache (memory and disk).
        allow_download: let :func:`load_clip` try the network.
    """

    name = "clip"

    def __init__(
        self,
        backbone: Any | None = None,
        model: str | None = None,
        device: str | torch.device | None = None,
        config: MaskFieldConfig | None = None,
        cache: GroundingCache | str | Path | None = None,
        input_size: tuple[int, int] | None = None,
        cache_features: bool = True,
        allow_download: bool = False,
    ) -> None:
        if backbone is None:
            from abm.grounding.clip import DEFAULT_MODEL, load_clip

            backbone = load_clip(model or DEFAULT_MODEL, device=device, allow_download=allow_download)
        self.backbone = backbone
        self.config = config or MaskFieldConfig()
        self.cache = cache if isinstance(cache, GroundingCache) else GroundingCache(cache)
        self.input_size = tuple(input_size) if input_size is not None else None
        self.cache_features = cache_features
        self.backbone_calls = 0  # images sent through the vision encoder (for tests and profiling)
        self._text_memory: dict[str, np.ndarray] = {}

    @property
    def model_name(self) -> str:
        return str(self.backbone.name)

    # ---- features ---------------------------------------------------------------------------------
    def camera_patch_features(self, observation: Observation, camera_names: Sequence[str]) -> dict[str, np.ndarray]:
        """camera name -> ``(h, w, D)`` float32 MaskCLIP patch features; uncached images run in one batch."""
        out: dict[str, np.ndarray] = {}
        todo: list[tuple[str, str]] = []
        for name in camera_names:
            key = content_key("patch", image_key(observation.camera(name).rgb), self.model_name, self.input_size)
            hit = self.cache.get(key) if self.cache_features else None
            if hit is not None:
                out[name] = hit["features"].astype(np.float32)
            else:
                todo.append((name, key))
        if todo:
            grids = self.backbone.dense_features([observation.camera(n).rgb for n, _ in todo], self.input_size)
            self.backbone_calls += len(todo)
            for i, (name, key) in enumerate(todo):
                out[name] = grids[i].float().cpu().numpy()
                if self.cache_features:
                    self.cache.put(key, {"features": out[name]})
        return out

    def point_features(self, observation: Observation, cloud: PointCloud) -> np.ndarray:
        """``(N, D)`` float32 unit-length CLIP feature of every point of ``cloud`` (the Feature Cloud)."""
        from abm.grounding.feature_cloud import lift_patch_features

        _check_cloud(observation, cloud)
        patch = self.camera_patch_features(observation, cloud.camera_names)
        sizes = {n: (observation.camera(n).height, observation.camera(n).width) for n in cloud.camera_names}
        return lift_patch_features(cloud, patch, sizes)

    def text_features(self, prompts: Sequence[str]) -> np.ndarray:
        """``(K, D)`` float32 unit-length text features (memoised per prompt)."""
        todo = [p for p in dict.fromkeys(prompts) if p not in self._text_memory]
        if todo:
            feats = self.backbone.text_features(todo).cpu().numpy()
            self._text_memory.update(zip(todo, feats, strict=True))
        return np.stack([self._text_memory[p] for p in prompts]) if prompts else np.zeros((0, 0), np.float32)

    def skill_embeddings(self, texts: Sequence[str]) -> torch.Tensor:
        """``(B, 77, D_text)`` float32 CPU token embeddings of the skill texts (cached per text)."""
        if isinstance(texts, str):
            texts = [texts]
        rows: dict[str, np.ndarray] = {}
        todo = []
        for t in dict.fromkeys(texts):
            hit = self.cache.get(content_key("skill", t, self.model_name))
            if hit is not None:
                rows[t] = hit["tokens"]
            else:
                todo.append(t)
        if todo:
            tokens = self.backbone.text_tokens(todo).cpu().numpy()
            for t, row in zip(todo, tokens, strict=True):
                rows[t] = row
                self.cache.put(content_key("skill", t, self.model_name), {"tokens": row})
        return torch.from_numpy(np.stack([rows[t] for t in texts]).astype(np.float32))

    # ---- grounding ---------------------------------------------------------------------------------
    def ground(
        self,
        observation: Observation,
        cloud: PointCloud,
        target: str,
        object_names: Mapping[int, str] | None = None,
    ) -> MaskField:
        """Mask field of ``target`` over ``cloud`` (``object_names`` is not used by CLIP)."""
        _check_cloud(observation, cloud)
        prompt = clip_prompt(target)
        key = content_key(
            "mask", cloud_key(cloud), *(image_key(observation.camera(n).rgb) for n in cloud.camera_names),
            self.model_name, self.input_size, prompt, self.config.key(),
        )
        hit = self.cache.get(key)
        if hit is not None:
            return MaskField(hit["mask"], hit["heatmap"], bool(hit["found"]), target, prompt, hit["similarity"])
        feats = self.point_features(observation, cloud)
        text = self.text_features([prompt])[0]
        negatives = None
        if self.config.normalization == "softmax":
            negatives = self.text_features(negative_prompts(self.config.negatives))
        field = mask_field_from_features(feats, text, negatives, self.config, target, prompt)
        self.cache.put(key, {"mask": field.mask, "heatmap": field.heatmap, "found": np.array(field.found),
                             "similarity": field.similarity})
        return field


def override_spec(kind: str | None, clip_model: str | None = None) -> dict[str, Any] | None:
    """The grounder spec of the ``--grounder KIND [--clip-model M]`` flags of ``abm eval`` and ``abm run``.

    ``None`` keeps the checkpoint's grounder; ``clip_model`` names the CLIP weights of the ``clip`` grounder,
    or of the grounder ``tracking`` grounds the first step with. Options it does not name (threshold,
    normalisation) stay those stored in the checkpoint (:meth:`abm.policy.KeyframePolicy.from_checkpoint`).
    """
    if clip_model is None:
        return {"kind": kind} if kind else None
    if kind == "clip":
        return {"kind": "clip", "model": clip_model}
    if kind == "tracking":
        return {"kind": "tracking", "inner": {"kind": "clip", "model": clip_model}}
    raise ValueError(f"--clip-model applies to --grounder clip or tracking, not {kind or 'the checkpoint default'!r}: "
                     f"add --grounder clip to ground with {clip_model}")


def make_grounder(kind: str = "oracle", **kwargs: Any) -> Grounder:
    """Build a grounder by name.

    ``make_grounder("oracle")``; ``make_grounder("clip", model="openai/clip-vit-large-patch14-336" | DIR |
    "tiny", device="cpu", config=MaskFieldConfig(...), cache=DIR)``; ``make_grounder("tracking",
    inner={"kind": "clip", ...}, radius=0.01)`` grounds once per episode with ``inner`` and then tracks
    (:class:`abm.grounding.tracking.TrackingGrounder`). Keyword ``normalization`` and ``threshold`` are
    accepted as shortcuts for the clip config.
    """
    if kind == "oracle":
        if kwargs:
            raise TypeError(f"the oracle grounder takes no options, got {sorted(kwargs)}")
        return OracleGrounder()
    if kind == "clip":
        shortcuts = {k: kwargs.pop(k) for k in ("normalization", "threshold", "negatives", "logit_scale")
                     if k in kwargs}
        if shortcuts:
            if "config" in kwargs:
                raise TypeError("pass either config or its fields (normalization, threshold, ...), not both")
            kwargs["config"] = MaskFieldConfig(**shortcuts)
        return ClipGrounder(**kwargs)
    if kind == "tracking":
        from abm.grounding.tracking import TrackingGrounder

        inner = kwargs.pop("inner", {"kind": "oracle"})
        inner = dict(inner) if isinstance(inner, Mapping) else {"kind": str(inner)}
        return TrackingGrounder(make_grounder(inner.pop("kind", "oracle"), **inner), **kwargs)
    raise ValueError(f"unknown grounder {kind!r}; choose from {list(GROUNDERS)}")
