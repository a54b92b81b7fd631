"""Grounders: observation + point cloud + target description -> :class:`MaskField`.

All grounders share one call::

    field = grounder.ground(observation, cloud, target, object_names)

* :class:`ClipGrounder` — the method: CLIP Feature Cloud + text prompt -> normalised heatmap -> mask
  (``mode="field"``, the paper's per-point field), or 3-D object proposals scored by CLIP, the mask being
  the best candidate's points (``mode="proposals"``, :mod:`abm.grounding.proposals`).
* :class:`~abm.grounding.tracking.TrackingGrounder` — grounds once with another grounder, then tracks
  the target's 3-D points from step to step.
* :class:`OracleGrounder` — simulator segmentation + object names: the points whose segmentation id is
  named ``target``. An upper bound, and the default where real CLIP weights are unavailable.

Build them from their typed configurations with :func:`abm.grounding.config.build_grounder`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, cast, runtime_checkable

import numpy as np
import torch
from numpy.typing import NDArray

from abm.errors import ConfigError
from abm.geometry import PointCloud
from abm.grounding.cache import GroundingCache, cloud_key, content_key, image_key
from abm.grounding.clip import ClipBackbone, load_clip_model, model_fingerprint
from abm.grounding.config import (  # the defaults live with the typed configurations
    CLIP_MODES,
    DEFAULT_CLIP_MODE,
    DEFAULT_DENSE_MODE,
    DEFAULT_INPUT_SIZE,
    DEFAULT_SCALES,
    DENSE_MODES,
    ClipGrounderConfig,
    ClipModelConfig,
    GrounderConfig,
    MaskFieldConfig,
    OracleGrounderConfig,
    ProposalConfig,
    grounder_config_from_dict,
)
from abm.grounding.decision import normalize_name
from abm.grounding.feature_cloud import LiftedFeatures, lift_patch_features, lift_patch_index
from abm.grounding.mask_field import MaskField, mask_field_from_features, negative_prompts
from abm.grounding.proposals import object_proposals, with_base_points
from abm.language.instruction import clip_prompt
from abm.types import Observation


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
    segmentations = {n: observation.camera(n).segmentation for n in cloud.camera_names}
    missing = [n for n, seg in segmentations.items() if seg is None]
    if missing:
        raise ConfigError(f"cameras {missing} have no segmentation; the oracle grounder needs simulator "
                          "segmentation (use the clip grounder on real data)")
    ids: np.ndarray = cloud.gather({n: seg for n, seg in segmentations.items() if seg is not None})
    return ids


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
    is in the cloud (the mask is then empty). ``confidence`` is 1.0 when found, else 0.0.
    """

    name = "oracle"

    @classmethod
    def from_config(cls, config: OracleGrounderConfig, **runtime: Any) -> OracleGrounder:
        """The oracle of its (option-less) configuration (:data:`abm.grounding.config.GROUNDERS`' builder)."""
        if runtime:
            raise ConfigError(f"the oracle grounder takes no options, got {sorted(runtime)}")
        return cls()

    def ground(
        self,
        observation: Observation,
        cloud: PointCloud,
        target: str,
        object_names: Mapping[int, str] | None = None,
    ) -> MaskField:
        _check_cloud(observation, cloud)
        if not object_names:
            raise ConfigError("the oracle grounder needs the episode's object_names (segmentation id -> name)")
        mask = target_point_mask(observation, cloud, target, object_names).astype(np.float32)
        found = bool(mask.any())
        return MaskField(mask, mask.copy(), found, target, "", confidence=float(found))


CROP_MEMORY = 1024
"""Crop embeddings a :class:`ClipGrounder` keeps (:meth:`ClipGrounder.crop_embeddings`; 1 MiB at D = 128)."""


class ClipGrounder:
    """The ABM grounder: MaskCLIP feature cloud, prompt ``"a photo of a X"``, normalised heatmap, threshold.

    Args:
        backbone: a ready :class:`~abm.grounding.clip.ClipBackbone`; else one is loaded from ``model``.
        model: hub name, local directory, ``"tiny"`` or ``"random:<preset>"`` (:func:`~abm.grounding.clip.load_clip`).
        device: torch device for the backbone (default CUDA when available).
        config: normalisation / threshold settings (:class:`MaskFieldConfig`).
        cache: a :class:`GroundingCache`, a directory for one, or None for a memory-only cache.
        input_size: ``(H, W)`` (or one side) the camera images are resized to (default the model's native
            size); a larger input gives a finer patch grid (interpolated position embeddings).
        cache_features: also keep per-image patch features in the cache (memory and disk).
        allow_download: let :func:`~abm.grounding.clip.load_clip` try the network.
        dense_mode: last block of the dense features (:data:`abm.grounding.config.DENSE_MODES`: ``maskclip``,
            ``clearclip``, ``sclip``, ``naclip``).
        mode: ``"field"`` (threshold the per-point heatmap) or ``"proposals"`` (score 3-D object candidates,
            mask the best one; ``config.negatives`` still decide ``found``).
        proposals: :class:`~abm.grounding.proposals.ProposalConfig` (or its fields as a mapping) for
            ``mode="proposals"``.
        scales: extra input sides (e.g. ``(256,)``): the point features are the normalised mean of the
            features lifted from ``input_size`` and from each of these sizes (multi-scale).
    """

    name = "clip"

    def __init__(
        self,
        backbone: ClipBackbone | None = None,
        model: str | None = None,
        device: str | torch.device | None = None,
        config: MaskFieldConfig | None = None,
        cache: GroundingCache | str | Path | None = None,
        input_size: int | tuple[int, ...] | None = None,
        cache_features: bool = ClipGrounderConfig.cache_features,
        allow_download: bool = ClipGrounderConfig.allow_download,
        dense_mode: str = DEFAULT_DENSE_MODE,
        mode: str = DEFAULT_CLIP_MODE,
        proposals: ProposalConfig | Mapping[str, Any] | None = None,
        scales: Sequence[int] | None = None,
    ) -> None:
        if dense_mode not in DENSE_MODES:
            raise ConfigError(f"dense_mode must be one of {DENSE_MODES}, got {dense_mode!r}")
        if mode not in CLIP_MODES:
            raise ConfigError(f"mode must be one of {CLIP_MODES}, got {mode!r}")
        if backbone is None:
            device_name = None if device is None else str(device)
            backbone = load_clip_model(ClipModelConfig(model, device_name, allow_download))
        self.backbone = backbone
        self.config = config or MaskFieldConfig()
        self.cache = cache if isinstance(cache, GroundingCache) else GroundingCache(cache)
        if input_size is None and DEFAULT_INPUT_SIZE is not None:
            input_size = DEFAULT_INPUT_SIZE
        if isinstance(input_size, int):
            input_size = (input_size, input_size)
        # (H, W): ClipBackbone.preprocess unpacks two sides (a configuration read from JSON holds a list)
        self.input_size = cast("tuple[int, int] | None", tuple(input_size) if input_size is not None else None)
        self.dense_mode = dense_mode
        self.mode = mode
        self.scales = tuple(int(v) for v in (DEFAULT_SCALES if scales is None else scales))
        if not isinstance(proposals, ProposalConfig):
            proposals = ProposalConfig(**(proposals or {}))
        self.proposal_config = proposals
        self.cache_features = cache_features
        self.backbone_calls = 0  # images sent through the vision encoder (for tests and profiling)
        self._text_memory: dict[str, np.ndarray] = {}
        self._crop_memory: dict[str, NDArray[np.float64]] = {}  # crop digest -> embedding (crop_embeddings)

    @classmethod
    def from_config(cls, config: ClipGrounderConfig, **runtime: Any) -> ClipGrounder:
        """The grounder of a typed configuration (:data:`abm.grounding.config.GROUNDERS`' builder); ``runtime``
        (``backbone=`` a loaded model, ``cache=`` a cache object) overrides the constructor's arguments. The backbone
        is the configuration's :class:`~abm.grounding.config.ClipModelConfig` (:func:`load_clip_model`)."""
        kwargs: dict[str, Any] = dict(
            config=config.mask_field_config(), cache=config.cache, input_size=config.input_size,
            cache_features=config.cache_features, dense_mode=config.dense_mode, mode=config.mode,
            proposals=config.proposals, scales=config.scales)
        kwargs.update(runtime)
        if kwargs.get("backbone") is None:
            kwargs["backbone"] = load_clip_model(config.clip_model())
        return cls(**kwargs)

    def exact_memories(self) -> tuple[object, ...]:
        """The objects that only remember results this grounder computes exactly the same again (the backbone,
        whose weights are frozen; the text features, the crop embeddings and the results cache): a copy of the
        grounder for another rollout may share them instead of copying them
        (:func:`abm.evaluation.policies.load_policy`)."""
        return self.backbone, self._text_memory, self._crop_memory, self.cache

    def share_memories(self, other: ClipGrounder) -> None:
        """Remember into ``other``'s text features, crop embeddings and (when both are memory-only) results
        cache from now on, so two grounders of the same backbone compute each crop, text and grounding once
        (the results are those each computes alone: the memories are exact, and the results cache is keyed by
        everything a result depends on). Raises ``ValueError`` for another backbone."""
        if other.model_name != self.model_name:
            raise ValueError(f"cannot share the memories of CLIP {other.model_name!r} with CLIP {self.model_name!r}")
        self._text_memory, self._crop_memory = other._text_memory, other._crop_memory
        if self.cache.directory is None and other.cache.directory is None:
            self.cache = other.cache

    @property
    def model_name(self) -> str:
        """The backbone's identity in cache keys (its content digest for a local folder)."""
        return str(self.backbone.fingerprint or self.backbone.name)

    def _dense_key(self) -> tuple[str, ...]:
        """Cache-key parts of the dense-feature option (none for MaskCLIP, so older caches stay valid)."""
        return () if self.dense_mode == "maskclip" else (f"dense={self.dense_mode}",)

    def _scales_key(self) -> tuple[str, ...]:
        return (f"scales={self.scales}",) if self.scales else ()

    def _hand_key(self, observation: Observation) -> tuple[str, ...]:
        """Cache-key part of the gripper pose and opening, which the proposals' hand filter reads (0.1 mm)."""
        if self.mode != "proposals" or not self.proposal_config.hand_filter:
            return ()
        pose = np.asarray(observation.gripper_pose)[:3].ravel()
        return ("gripper=" + ",".join(f"{v:.4f}" for v in (*pose, float(observation.gripper_open))),)

    def _mode_key(self) -> tuple[str, ...]:
        """Cache-key parts of the grounding mode (none for the per-point field)."""
        return () if self.mode == "field" else (f"mode={self.mode}", self.proposal_config.key())

    # ---- features ---------------------------------------------------------------------------------
    def camera_patch_features(self, observation: Observation, camera_names: Sequence[str],
                              input_size: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
        """camera name -> ``(h, w, D)`` float32 MaskCLIP patch features; uncached images run in one batch.
        ``input_size`` overrides the grounder's own (for the extra ``scales``)."""
        input_size = input_size or self.input_size
        out: dict[str, np.ndarray] = {}
        todo: list[tuple[str, str]] = []
        for name in camera_names:
            key = content_key("patch", image_key(observation.camera(name).rgb), self.model_name, input_size,
                              *self._dense_key())
            hit = self.cache.get(key) if self.cache_features else None
            if hit is not None:
                out[name] = hit["features"].astype(np.float32)
            else:
                todo.append((name, key))
        if todo:
            grids = self.backbone.dense_features([observation.camera(n).rgb for n, _ in todo], input_size,
                                                 **({} if self.dense_mode == "maskclip" else {"mode": self.dense_mode}))
            self.backbone_calls += len(todo)
            for i, (name, key) in enumerate(todo):
                out[name] = grids[i].float().cpu().numpy()
                if self.cache_features:
                    self.cache.put(key, {"features": out[name]})
        return out

    def lifted_features(self, observation: Observation, cloud: PointCloud) -> LiftedFeatures | NDArray[np.float32]:
        """:meth:`point_features` as a patch table and each point's row in it (:class:`LiftedFeatures`), or the
        ``(N, D)`` array itself with extra ``scales`` (whose mean is per point)."""
        if self.scales:
            return self.point_features(observation, cloud)
        _check_cloud(observation, cloud)
        patch = self.camera_patch_features(observation, cloud.camera_names)
        sizes = {n: (observation.camera(n).height, observation.camera(n).width) for n in cloud.camera_names}
        return LiftedFeatures(*lift_patch_index(cloud, patch, sizes))

    def point_features(self, observation: Observation, cloud: PointCloud) -> NDArray[np.float32]:
        """``(N, D)`` float32 unit-length CLIP feature of every point of ``cloud`` (the Feature Cloud)."""
        _check_cloud(observation, cloud)
        patch = self.camera_patch_features(observation, cloud.camera_names)
        sizes = {n: (observation.camera(n).height, observation.camera(n).width) for n in cloud.camera_names}
        feats = lift_patch_features(cloud, patch, sizes)
        if not self.scales:
            return feats
        for side in self.scales:
            patch = self.camera_patch_features(observation, cloud.camera_names, (side, side))
            feats = feats + lift_patch_features(cloud, patch, sizes)
        unit: NDArray[np.float32] = feats / np.maximum(np.linalg.norm(feats, axis=1, keepdims=True), 1e-8)
        return unit

    def text_features(self, prompts: Sequence[str]) -> np.ndarray:
        """``(K, D)`` float32 unit-length text features (memoised per prompt).

        Each prompt is encoded on its own: in a batch, the padding to the longest prompt and the batch size change
        the float sums in the last bits, so a prompt's features (and a borderline mask) would depend on which
        prompts happened to be encoded with it first."""
        todo = [p for p in dict.fromkeys(prompts) if p not in self._text_memory]
        for prompt in todo:
            self._text_memory[prompt] = self.backbone.text_features([prompt]).cpu().numpy()[0]
        return np.stack([self._text_memory[p] for p in prompts]) if prompts else np.zeros((0, 0), np.float32)

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
            self.model_name, self.input_size, prompt, self.config.key(), *self._dense_key(), *self._mode_key(),
            *self._scales_key(), *self._hand_key(observation),
        )
        hit = self.cache.get(key)
        if hit is not None:
            confidence = float(hit["confidence"]) if "confidence" in hit else None  # older entries: derived
            return MaskField(hit["mask"], hit["heatmap"], bool(hit["found"]), target, prompt, hit.get("similarity"),
                             confidence)
        field = self._ground_proposals(observation, cloud, target, prompt) if self.mode == "proposals" else None
        if field is None:
            feats = self.point_features(observation, cloud)
            text = self.text_features([prompt])[0]
            negatives = None
            if self.config.normalization == "softmax":
                negatives = self.text_features(negative_prompts(self.config.negatives))
            field = mask_field_from_features(feats, text, negatives, self.config, target, prompt)
        entry = {"mask": field.mask, "heatmap": field.heatmap, "found": np.array(field.found),
                 "confidence": np.array(field.confidence, np.float64)}
        if field.similarity is not None:  # None (crop scoring) is left out: np.load refuses object arrays
            entry["similarity"] = field.similarity
        self.cache.put(key, entry)
        return field


    def candidate_scores(self, observation: Observation, cloud: PointCloud, candidates: Sequence[np.ndarray],
                         texts: np.ndarray, feats: LiftedFeatures | np.ndarray | None) -> np.ndarray:
        """``(C, T)`` CLIP scores of point-index candidates against unit text features ``texts`` ``(T, D)``
        (``feats``: the point features, :meth:`lifted_features`):
        the configured mix of the dense score (cosine of the candidate's mean point feature) and the crop
        score (pixel-weighted mean cosine of the CLIP image embeddings of its camera crops)."""
        cfg = self.proposal_config
        out = np.zeros((len(candidates), len(texts)), np.float64)
        if cfg.scoring != "crop":
            assert feats is not None
            mean = np.stack([feats[c].mean(0) for c in candidates])
            mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-8)
            dense = mean @ texts.T
            out += dense if cfg.scoring == "dense" else (1.0 - cfg.crop_weight) * dense
        if cfg.scoring != "dense":
            chosen = np.arange(len(candidates))
            if cfg.scoring == "combined" and 0 < cfg.crop_top_k < len(candidates):
                chosen = np.sort(np.argsort(-dense[:, 0], kind="stable")[:cfg.crop_top_k])
            crops, owner, weight = candidate_crops(observation, cloud, [candidates[int(i)] for i in chosen], cfg)
            owner = chosen[owner]
            crop = np.zeros_like(out)
            if crops:
                sims = self.crop_embeddings(crops) @ texts.T
                total = np.bincount(owner, weights=weight, minlength=len(candidates))
                for t in range(len(texts)):
                    crop[:, t] = np.bincount(owner, weights=weight * sims[:, t], minlength=len(candidates))
                seen = total > 0
                crop[seen] /= total[seen][:, None]
                crop[~seen] = -1.0  # no camera sees it well enough: never preferred by its crops
            out += crop if cfg.scoring == "crop" else cfg.crop_weight * crop
        return out

    def crop_embeddings(self, crops: Sequence[np.ndarray]) -> NDArray[np.float64]:
        """``(C, D)`` float64 unit CLIP image embeddings of ``uint8`` ``(h, w, 3)`` image crops.

        Each distinct crop (by its pixels) goes through the vision encoder once per grounder: the new crops of a
        call in one batch, the ones met before from memory (an object nothing moved or covered gives the same
        crop at the next step of a rollout: about a third of a step's crops). The memory is exact, not an
        approximation: :meth:`ClipBackbone.image_features` gives an image the same embedding whatever else is in
        its batch. It keeps the :data:`CROP_MEMORY` latest crops."""
        side = (self.backbone.image_size, self.backbone.image_size)
        keys = [image_key(c) for c in crops]
        todo = {k: c for k, c in zip(keys, crops, strict=True) if k not in self._crop_memory}
        if todo:
            emb = self.backbone.image_features(list(todo.values()), side).cpu().numpy().astype(np.float64)
            self.backbone_calls += len(todo)
            self._crop_memory.update(zip(todo, emb, strict=True))
        out = np.stack([self._crop_memory[k] for k in keys])
        for k in keys:  # the latest use last: what the memory drops first is what was met longest ago
            self._crop_memory[k] = self._crop_memory.pop(k)
        while len(self._crop_memory) > CROP_MEMORY:
            del self._crop_memory[next(iter(self._crop_memory))]
        return out

    def _ground_proposals(self, observation: Observation, cloud: PointCloud, target: str, prompt: str
                          ) -> MaskField | None:
        """The best-scoring 3-D object candidate as the mask (None when the cloud has no candidate)."""
        cfg = self.proposal_config
        props = object_proposals(cloud.xyz, cloud.rgb, cfg, observation.gripper_pose,
                                 float(observation.gripper_open))
        if not len(props):
            return None
        texts = self.text_features([prompt, *negative_prompts(self.config.negatives)]).astype(np.float64)
        feats = self.lifted_features(observation, cloud) if cfg.scoring != "crop" else None
        scores = self.candidate_scores(observation, cloud, props.candidates, texts, feats)
        best = int(np.argmax(scores[:, 0]))
        found = bool(len(texts) == 1 or scores[best, 0] > scores[best, 1:].max())
        logits = self.backbone.logit_scale * (scores[:, 0] - scores[best, 0])
        probs = np.exp(logits) / np.exp(logits).sum()
        heat = np.zeros(len(cloud), np.float32)
        for c, p in zip(props.candidates, probs, strict=True):
            heat[c] = np.maximum(heat[c], p)
        chosen = with_base_points(cloud.xyz, cloud.rgb, props.candidates[best], props.table, cfg.voxel,
                                  cfg.color_tol)
        heat[chosen] = np.maximum(heat[chosen], probs[best])
        mask = np.zeros(len(cloud), np.float32)
        mask[chosen] = 1.0
        sim = point_similarity(feats, texts[0]) if feats is not None else None
        # confidence: the chosen object's probability among all candidates (about 1/k for k look-alikes)
        return MaskField(mask, heat, found, target, prompt, sim, float(probs[best]))


SIMILARITY_ROWS = 1024
"""Points per block of :func:`point_similarity` (a block's float64 copy, 1 MiB at D = 128, stays in cache)."""


def point_similarity(feats: LiftedFeatures | NDArray[np.float32], text: NDArray[np.float64]) -> NDArray[np.float32]:
    """``(N,)`` float32 cosine of every point feature ``(N, D)`` float32 with a unit text feature ``(D,)`` float64,
    computed in float64 as ``(feats @ text).astype(float32)`` computes it (each row's dot product is the same
    whatever rows are beside it), in blocks of :data:`SIMILARITY_ROWS` points (a block's float64 copy stays in
    cache); of :class:`LiftedFeatures`, once per patch."""
    if isinstance(feats, LiftedFeatures):
        return point_similarity(feats.table, text)[feats.index]
    out = np.empty(len(feats), np.float32)
    for start in range(0, len(feats), SIMILARITY_ROWS):
        out[start:start + SIMILARITY_ROWS] = feats[start:start + SIMILARITY_ROWS] @ text
    return out


def candidate_crops(observation: Observation, cloud: PointCloud, candidates: Sequence[np.ndarray],
                    config: ProposalConfig) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Square camera crops around each candidate: ``(crops, owner candidate per crop, weight per crop)``.

    A crop is cut from the ``config.crop_cameras`` cameras that see most of the candidate's points (at least
    ``min_crop_pixels``), around the box of those pixels, ``crop_margin`` times its larger side (as the
    benchmark CLIP's training crops, 1.3-2.4x), moved to lie inside the image. Weight: the pixels seen.
    """
    crops: list[np.ndarray] = []
    owner: list[int] = []
    weight: list[float] = []
    n_cams = len(cloud.camera_names)
    for i, members in enumerate(candidates):
        cams = cloud.camera_index[members]
        counts = np.bincount(cams, minlength=n_cams)
        for ci in np.argsort(-counts, kind="stable")[:config.crop_cameras]:
            if counts[ci] < config.min_crop_pixels:
                break
            rgb = observation.camera(cloud.camera_names[ci]).rgb
            height, width = rgb.shape[:2]
            px = cloud.pixels[members[cams == ci]]
            lo, hi = px.min(0), px.max(0) + 1
            side = int(min(max(np.ceil((hi - lo).max() * config.crop_margin), 8), height, width))
            centre = (lo + hi) / 2.0
            top = int(np.clip(round(centre[0] - side / 2), 0, height - side))
            left = int(np.clip(round(centre[1] - side / 2), 0, width - side))
            crops.append(rgb[top:top + side, left:left + side])
            owner.append(i)
            weight.append(float(counts[ci]))
    return crops, np.asarray(owner, np.int64), np.asarray(weight, np.float64)


def resolved_spec(spec: GrounderConfig | Mapping[str, Any]) -> dict[str, Any]:
    """A grounder's dict form naming everything its masks depend on, for cache keys: its kind's
    :meth:`~abm.grounding.config.GrounderConfig.cache_spec` (the CLIP grounder's names its model by
    :func:`~abm.grounding.clip.model_fingerprint` and the current defaults of the options it leaves out)."""
    config = spec if isinstance(spec, GrounderConfig) else grounder_config_from_dict(spec)
    return config.cache_spec(model_fingerprint)
