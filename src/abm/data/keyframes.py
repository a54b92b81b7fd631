"""Keyframe dataset: episodes -> model inputs of one policy variant.

Per sample (episode ``e``, keyframe ``k``):

1. fuse the cameras into a point cloud (:func:`abm.geometry.fuse_cameras`), cropped to the workspace
   cube grown by what augmentation can bring into view (so shifted / rotated samples have no empty
   bands; the renderer does the final crop to the cube after augmentation);
2. conditioning *before* augmentation, per point: the mask field of the target object (mask
   variants; from the grounder, cached on disk for non-oracle grounders) and the CLIP point features
   (``ifd``; cached on disk); the language goal is looked up in a per-text cache built once;
3. SE(3) augmentation of the points, the action and the gripper position together;
4. re-rendering into the virtual views, carrying ``[mask, heatmap, point index]`` as extra channels,
   and turning them into the variant's mask channel / CLIP feature index map;
5. targets: the action's position, rotation bins, gripper and ignore-collision flags.

Sampling is a pure function of ``(seed, global sample position)``: :class:`StepSampler` yields
``(index, sample_seed)`` keys and the augmentation is seeded by ``sample_seed`` alone, so the data
stream does not depend on the number of DataLoader workers and resumes exactly at any step. Nothing
unpicklable is held (episodes are loaded lazily by index; grounders and encoders are only used in
the main process), so multiple workers work.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from abm.geometry import PointCloud, Workspace, augment_scene, fuse_cameras, transform_points
from abm.policy.action_coding import encode_action, proprioception
from abm.policy.conditioning import (
    PointMask,
    ground_points,
    language_text,
    make_grounder_from_spec,
    split_instruction,
)
from abm.policy.config import PolicyConfig
from abm.policy.language import LanguageEncoder, encode_unique
from abm.policy.variants import mask_channel
from abm.render import OrthographicRenderer
from abm.types import Episode, KeyframeAction, Observation


@dataclass
class EpisodeMeta:
    """What the dataset needs to know about an episode without loading its images."""

    task: str
    instruction: str
    object_names: dict[int, str]
    target_names: list[str]
    num_steps: int
    key: str  # stable identifier (file path or in-memory position) for caches


class EpisodeSource:
    """Uniform, picklable access to episodes held in memory or in an on-disk ``EpisodeStore``.

    Args:
        episodes: a list of :class:`Episode`, or an ``EpisodeStore`` (anything with ``episodes``,
            ``load(i)`` and ``load_step(i, k)``).
        indices: which episodes to use (default all).
    """

    def __init__(self, episodes: Sequence[Episode] | Any, indices: Sequence[int] | None = None) -> None:
        self.in_memory = isinstance(episodes, (list, tuple))
        self.episodes = episodes
        n = len(episodes) if self.in_memory else len(episodes.episodes)
        self.indices = list(range(n)) if indices is None else list(indices)
        self.meta = [self._meta(i) for i in self.indices]

    def _meta(self, i: int) -> EpisodeMeta:
        if self.in_memory:
            ep = self.episodes[i]
            return EpisodeMeta(ep.task, ep.instruction, dict(ep.object_names), list(ep.target_names), len(ep),
                               f"memory:{i}")
        store = self.episodes
        info = store.episodes[i]
        if getattr(info, "object_names", None) is not None and getattr(info, "target_names", None) is not None:
            src = info  # the store's index already has everything (no image is read)
        elif hasattr(store, "load_metadata"):
            src = store.load_metadata(i)
        elif (names := _read_h5_names(Path(info.path))) is not None:
            src = SimpleNamespace(task=info.task, instruction=info.instruction, object_names=names[0],
                                  target_names=names[1])
        else:
            src = store.load(i)  # fallback: reads the whole episode once
        steps = int(getattr(info, "num_keyframes", 0) or len(getattr(src, "steps", ())))
        return EpisodeMeta(src.task, src.instruction, {int(k): v for k, v in dict(src.object_names).items()},
                           list(src.target_names), steps, str(info.path))

    def __len__(self) -> int:
        return len(self.indices)

    def load_step(self, j: int, k: int) -> tuple[Observation, KeyframeAction]:
        """Observation and action of keyframe ``k`` of the ``j``-th selected episode."""
        if self.in_memory:
            return self.episodes[self.indices[j]].steps[k]
        return self.episodes.load_step(self.indices[j], k)


def _read_h5_names(path: Path) -> tuple[dict[int, str], list[str]] | None:
    """``(object_names, target_names)`` from the JSON attributes of an HDF5 episode file written by
    ``abm.data.episode_store.save_episode``, without reading images; ``None`` if unavailable."""
    if path.suffix != ".h5" or not path.is_file():
        return None
    try:
        import h5py

        with h5py.File(path, "r") as f:
            names = {int(k): str(v) for k, v in json.loads(f.attrs["object_names"]).items()}
            return names, [str(t) for t in json.loads(f.attrs["target_names"])]
    except (ImportError, OSError, KeyError, ValueError):
        return None


class StepSampler(Sampler[tuple[int, int]]):
    """Deterministic, resumable, rank-sharded sampling of ``(index, sample_seed)`` keys.

    The global stream visits a fresh permutation of the ``n`` samples every epoch (seeded by
    ``(seed, epoch)``); training step ``s`` consumes global positions ``[s * B * W, (s + 1) * B * W)``
    and rank ``r`` takes its contiguous ``B`` of them — the same sharding as
    ``DistributedSampler`` but resumable mid-epoch at any step.

    Args:
        n: dataset size.
        batch_size: per-rank batch ``B``.
        steps: last step (exclusive) to produce samples for.
        start_step: first step.
        world_size: ranks ``W``; rank: this rank.
        seed: stream seed.
    """

    def __init__(self, n: int, batch_size: int, steps: int, start_step: int = 0, world_size: int = 1,
                 rank: int = 0, seed: int = 0) -> None:
        if n <= 0:
            raise ValueError("the dataset is empty: no keyframes match the selection")
        self.n, self.batch, self.steps, self.start = n, batch_size, steps, start_step
        self.world, self.rank, self.seed = world_size, rank, seed
        self._perm_epoch = -1
        self._perm = np.arange(n)

    def __len__(self) -> int:
        return max(self.steps - self.start, 0) * self.batch

    def key(self, position: int) -> tuple[int, int]:
        """``(index, sample_seed)`` at a global stream position."""
        epoch, i = divmod(position, self.n)
        if epoch != self._perm_epoch:
            self._perm = np.random.default_rng([self.seed, epoch]).permutation(self.n)
            self._perm_epoch = epoch
        return int(self._perm[i]), int(position)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        for step in range(self.start, self.steps):
            base = (step * self.world + self.rank) * self.batch
            for j in range(self.batch):
                yield self.key(base + j)


def worker_init(worker_id: int) -> None:
    """DataLoader ``worker_init_fn``: distinct, reproducible global RNG seeds per worker (the samples
    themselves are seeded by their key, see :class:`StepSampler`)."""
    seed = torch.initial_seed() % 2**32
    np.random.seed(seed)  # noqa: NPY002 - seeds third-party code using the global RNG
    random.seed(seed)


def collate(samples: Sequence[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Stack samples; ``ifd_features`` ``(M_i, D)`` are zero-padded to the largest ``M``."""
    out: dict[str, torch.Tensor] = {}
    for key in samples[0]:
        vals = [s[key] for s in samples]
        if key == "ifd_features":
            m = max(v.shape[0] for v in vals)
            padded = torch.zeros(len(vals), max(m, 1), vals[0].shape[1], dtype=vals[0].dtype)
            for i, v in enumerate(vals):
                padded[i, : v.shape[0]] = v
            out[key] = padded
        else:
            out[key] = torch.stack(vals)
    return out


class KeyframeDataset(Dataset):
    """Samples of one policy variant over a set of episodes (see module docstring).

    Args:
        source: the episodes (:class:`EpisodeSource`, a list of episodes or an ``EpisodeStore``).
        config: the policy config (variant, views, resolution, language and feature sizes).
        language: encoder for the language goals (used once, here, to fill the text cache).
        grounder: grounder spec (``{"kind": "oracle"}`` or ``{"kind": "clip", ...}``).
        augment: apply SE(3) augmentation (translation ``max_translation`` m, yaw ``max_yaw_deg``).
        cache_dir: folder for cached grounding results / CLIP point features (needed for non-oracle
            grounders and ``ifd``).
        seed: base seed of the augmentation.
        camera_names: cameras to fuse (default all).

    Each item is a dict of tensors: ``images`` ``(V, 10, H, W)``, ``proprio`` ``(4,)``, ``lang``
    ``(L, D)``, ``position`` ``(3,)`` (m), ``rotation_bins`` ``(3,)``, ``gripper`` ``()``,
    ``collision`` ``()``, plus ``mask`` ``(V, 1, H, W)`` for mask variants and ``ifd_features``
    ``(M, F)`` / ``ifd_index`` ``(V, H, W)`` for ``ifd``.
    """

    def __init__(
        self,
        source: EpisodeSource | Sequence[Episode] | Any,
        config: PolicyConfig,
        language: LanguageEncoder,
        grounder: Mapping[str, Any] | None = None,
        augment: bool = True,
        cache_dir: str | Path | None = None,
        seed: int = 0,
        camera_names: Sequence[str] | None = None,
        max_translation: float = 0.125,
        max_yaw_deg: float = 45.0,
        show_progress: bool = True,
    ) -> None:
        self.source = source if isinstance(source, EpisodeSource) else EpisodeSource(source)
        self.config = config
        self.spec = config.spec
        self.grounder_spec = dict(grounder or {"kind": "oracle"})
        self.augment = augment
        self.seed = seed
        self.camera_names = list(camera_names) if camera_names is not None else None
        self.max_translation, self.max_yaw_deg = max_translation, max_yaw_deg
        self.workspace = Workspace(config.workspace_center, config.workspace_size)
        self.fuse_workspace = augmentation_margin_cube(self.workspace, max_translation, max_yaw_deg) \
            if augment else self.workspace
        self.items = [(j, k) for j, m in enumerate(self.source.meta) for k in range(m.num_steps)]
        if not self.items:
            raise ValueError("the dataset is empty: the selected episodes have no keyframes")
        # per-episode conditioning: target name and language text
        self.targets: list[str | None] = []
        texts = []
        for m in self.source.meta:
            target, skill = None, None
            if self.spec.uses_mask or self.spec.language == "skill":
                hint = m.target_names[0] if m.target_names else None
                target, skill = split_instruction(m.instruction, m.object_names, hint)
                if hint is not None and self.grounder_spec.get("kind") == "oracle":
                    target = hint  # ground truth for the oracle; X text for learned grounders
            self.targets.append(target)
            texts.append(language_text(self.spec, m.instruction, skill))
        self.texts = texts
        if language.tokens != config.lang_tokens or language.dim != config.lang_dim:
            raise ValueError(
                f"language encoder gives {language.tokens} x {language.dim} tokens but the policy expects "
                f"{config.lang_tokens} x {config.lang_dim}"
            )
        self.lang_cache = encode_unique(language, texts)
        self._renderer: OrthographicRenderer | None = None
        self._oracle = None
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        needs_cache = (self.spec.uses_mask and self.grounder_spec.get("kind") != "oracle") or self.spec.clip_features
        if needs_cache:
            if self.cache_dir is None:
                raise ValueError(
                    f"variant {self.spec.name!r} with grounder {self.grounder_spec.get('kind')!r} needs a cache_dir "
                    "for grounding results / CLIP features"
                )
            self.precompute(show_progress)

    # ------------------------------------------------------------------ caching
    def _cache_file(self, j: int, k: int) -> Path:
        assert self.cache_dir is not None
        meta = self.source.meta[j]
        what = {"grounder": self.grounder_spec, "target": self.targets[j], "key": meta.key,
                "cameras": self.camera_names, "ws": [self.fuse_workspace.center, self.fuse_workspace.size]}
        digest = hashlib.sha1(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:16]
        return self.cache_dir / f"{digest}_k{k:03d}.npz"

    def precompute(self, show_progress: bool = True) -> None:
        """Compute (in this process) and cache grounding results and CLIP point features of every keyframe."""
        from tqdm import tqdm

        assert self.cache_dir is not None
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        todo = [(j, k) for j, k in self.items if not self._cache_file(j, k).exists()]
        if not todo:
            return
        grounder = make_grounder_from_spec(self.grounder_spec)
        for j, k in tqdm(todo, desc="grounding keyframes", disable=not show_progress):
            obs, _ = self.source.load_step(j, k)
            cloud = self._cloud(obs)
            arrays: dict[str, np.ndarray] = {}
            if self.spec.uses_mask:
                pm = ground_points(grounder, obs, cloud, self.targets[j], self.source.meta[j].object_names)
                arrays.update(mask=pm.mask.astype(np.float16), heatmap=pm.heatmap.astype(np.float16))
            if self.spec.clip_features:
                feats = np.asarray(grounder.point_features(obs, cloud), np.float32)
                if feats.shape != (len(cloud), self.config.ifd_feature_dim):
                    raise ValueError(
                        f"CLIP point features have shape {feats.shape}, expected ({len(cloud)}, "
                        f"{self.config.ifd_feature_dim}); set the policy's ifd_feature_dim to the CLIP width"
                    )
                arrays["features"] = feats.astype(np.float16)
            path = self._cache_file(j, k)
            tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
            np.savez(tmp, **arrays)
            os.replace(tmp, path)

    # ------------------------------------------------------------------ samples
    def __len__(self) -> int:
        return len(self.items)

    def _cloud(self, obs: Observation) -> PointCloud:
        return fuse_cameras(obs, self.fuse_workspace, self.camera_names)

    @property
    def renderer(self) -> OrthographicRenderer:
        if self._renderer is None:
            self._renderer = OrthographicRenderer(self.workspace, self.config.resolution, self.config.views)
        return self._renderer

    def _conditioning(self, j: int, k: int, obs: Observation, cloud: PointCloud
                      ) -> tuple[PointMask | None, np.ndarray | None]:
        if not (self.spec.uses_mask or self.spec.clip_features):
            return None, None
        if self.cache_dir is not None and (self.grounder_spec.get("kind") != "oracle" or self.spec.clip_features):
            path = self._cache_file(j, k)
            if not path.exists():
                raise FileNotFoundError(f"grounding cache entry {path} is missing; run precompute() first")
            with np.load(path) as data:
                pm = None
                if self.spec.uses_mask:
                    mask, heat = data["mask"].astype(np.float32), data["heatmap"].astype(np.float32)
                    pm = PointMask(mask, heat, bool(mask.any()))
                feats = data["features"].astype(np.float32) if self.spec.clip_features else None
            return pm, feats
        if self._oracle is None:
            self._oracle = make_grounder_from_spec({"kind": "oracle"})
        pm = ground_points(self._oracle, obs, cloud, self.targets[j], self.source.meta[j].object_names)
        return pm, None

    def __getitem__(self, key: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        index, sample_seed = (key, index_seed(key)) if isinstance(key, int) else key
        j, k = self.items[index]
        obs, action = self.source.load_step(j, k)
        cloud = self._cloud(obs)
        pm, feats = self._conditioning(j, k, obs, cloud)
        rng = np.random.default_rng([self.seed, sample_seed])
        points = cloud.xyz
        grip_pos = np.asarray(obs.gripper_pose[:3, 3], np.float64)
        if self.augment:
            points, action, transform = augment_scene(points, action, self.workspace, rng,
                                                      self.max_translation, self.max_yaw_deg)
            grip_pos = transform_points(transform, grip_pos[None])[0]
        sample = render_inputs(self.renderer, self.config, points, cloud.rgb, pm, feats)
        enc = encode_action(action, self.config.rotation_bins)
        sample.update(
            proprio=torch.from_numpy(proprioception(obs.gripper_open, grip_pos, self.workspace)),
            lang=self.lang_cache[self.texts[j]],
            position=torch.from_numpy(enc.position),
            rotation_bins=torch.from_numpy(enc.rotation_bins),
            gripper=torch.tensor(enc.gripper, dtype=torch.int64),
            collision=torch.tensor(enc.collision, dtype=torch.int64),
        )
        return sample


def augmentation_margin_cube(workspace: Workspace, max_translation: float, max_yaw_deg: float) -> Workspace:
    """The cube around ``workspace`` holding every point that augmentation can move into it.

    A source point is the inverse transform of a point in the cube: undo the shift (``max_translation`` per
    axis), then the yaw about the vertical through the centre, which sweeps a square of half-side ``a`` out
    to ``a * sqrt(2) * cos(45 deg - |yaw|)``.
    """
    yaw = np.radians(min(abs(max_yaw_deg), 45.0))
    reach = (workspace.half + max_translation) * np.sqrt(2.0) * np.cos(np.pi / 4 - yaw)
    return Workspace(workspace.center, 2.0 * reach)


def index_seed(index: int) -> int:
    """Sample seed used when a dataset is indexed by a plain integer."""
    return int(index)


def render_inputs(
    renderer: OrthographicRenderer,
    config: PolicyConfig,
    points: np.ndarray,
    rgb: np.ndarray,
    point_mask: PointMask | None,
    features: np.ndarray | None,
) -> dict[str, torch.Tensor]:
    """Render one point cloud into the model's image inputs for ``config``'s variant.

    Args:
        points: ``(N, 3)`` world metres (after augmentation).
        rgb: ``(N, 3)`` in ``[0, 1]``.
        point_mask: per-point mask field (mask variants).
        features: ``(N, F)`` per-point CLIP features (``ifd``).

    Returns:
        ``images`` ``(V, 10, H, W)``, and ``mask`` ``(V, 1, H, W)`` or ``ifd_features`` ``(M, F)`` +
        ``ifd_index`` ``(V, H, W)`` (index into ``ifd_features`` of the visible point, -1 = none).
    """
    spec = config.spec
    n = points.shape[0]
    extra = []
    if spec.uses_mask:
        if point_mask is None:
            raise ValueError(f"variant {spec.name!r} needs a per-point mask field")
        extra += [point_mask.mask, point_mask.heatmap]
    if spec.clip_features:
        extra.append(np.arange(n, dtype=np.float32))
    pts = torch.from_numpy(np.ascontiguousarray(points, np.float32))
    cols = torch.from_numpy(np.ascontiguousarray(rgb, np.float32))
    ext = torch.from_numpy(np.stack(extra, -1).astype(np.float32)) if extra else None
    with torch.no_grad():
        views = renderer.render(pts, cols, extra=ext)
    out = {"images": views.rvt_channels()[0].contiguous()}
    if spec.uses_mask:
        out["mask"] = mask_channel(spec, views.extra[:, :, :2])[0].contiguous()
    if spec.clip_features:
        if features is None:
            raise ValueError(f"variant {spec.name!r} needs per-point CLIP features")
        idx = views.extra[0, :, -1].round().long()
        idx = torch.where(views.occupied[0], idx, torch.full_like(idx, -1))
        visible, inverse = torch.unique(idx[idx >= 0], return_inverse=True)
        compact = torch.full_like(idx, -1)
        compact[idx >= 0] = inverse
        out["ifd_features"] = torch.from_numpy(np.asarray(features, np.float32))[visible]
        out["ifd_index"] = compact
    return out
