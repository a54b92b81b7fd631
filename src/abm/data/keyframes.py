"""Keyframe dataset: episodes -> policy-independent samples (:mod:`abm.samples`).

Per sample (episode ``e``, keyframe ``k``):

1. fuse the cameras into a point cloud, cropped to the workspace cube grown by what augmentation can
   bring into view (so shifted / rotated samples have no empty bands; the policy's renderer does the
   final crop to the cube), and condition it on the instruction
   (:func:`abm.grounding.conditioning.condition_cloud`): the target X and skill text (split once per
   episode), the per-point mask field of X (oracle: computed here; other grounders: read from the cache
   that the explicit grounding step :func:`ground_keyframes` / ``abm data ground`` fills) and per-point
   CLIP features (cached the same way); with ``destination``, the destination's mask field too (the
   task's declared destination, ``Task.destination``: ground truth for the oracle, the instruction's words for
   the other grounders, cached like the target's under the destination's name);
2. SE(3) augmentation of the points, the action and the gripper position together;
3. the sample: points, colours, per-point mask / features, gripper state, texts and the action targets.

The dataset knows nothing of policies: which conditioning to compute is given by three flags
(``split``, ``mask``, ``features``; a policy names them in ``KeyframePolicy.sample_options()``), and
rendering, language encoding and target coding happen inside the policy.

Sampling is a pure function of ``(seed, global sample position)``: :class:`StepSampler` yields
``(index, sample_seed)`` keys and the augmentation is seeded by ``sample_seed`` alone, so the data
stream does not depend on the number of DataLoader workers and resumes exactly at any step. Nothing
unpicklable is held (episodes are loaded lazily by index; grounders other than the oracle are only
used in the main process), so multiple workers work.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import random
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Protocol, TypeAlias, cast

import numpy as np
import torch
from numpy.typing import NDArray
from torch.utils.data import Dataset, Sampler

from abm.errors import ConfigError, DataError
from abm.files import atomic_path
from abm.geometry import Workspace, augment_cloud, transform_points
from abm.grounding.conditioning import ConditionedCloud, PointMask, condition_cloud
from abm.grounding.config import GROUNDERS, GrounderConfig, OracleGrounderConfig, as_grounder_config, build_grounder
from abm.grounding.feature_cloud import LiftedFeatures
from abm.grounding.grounders import Grounder, resolved_spec
from abm.language.roles import instruction_destination, split_roles
from abm.progress import Progress
from abm.samples import Sample, action_targets, cloud_sample, collate
from abm.sim.tasks import TASKS
from abm.types import Episode, KeyframeAction, Observation

__all__ = ["EpisodeMeta", "EpisodeSource", "KeyframeDataset", "StepSampler", "augmentation_margin_cube",
           "check_inside_workspace", "collate", "ground_keyframes", "worker_init"]


class EpisodeIndexEntry(Protocol):
    """What a store's index knows of one episode without reading it (e.g. ``EpisodeInfo``)."""

    @property
    def path(self) -> str | Path: ...
    @property
    def task(self) -> str: ...
    @property
    def instruction(self) -> str: ...


class EpisodeStoreLike(Protocol):
    """The ``EpisodeStore`` API the dataset relies on: an index without images, lazy per-step loading."""

    @property
    def episodes(self) -> Sequence[EpisodeIndexEntry]: ...
    def load(self, i: int) -> Episode: ...
    def load_step(self, i: int, k: int) -> tuple[Observation, KeyframeAction]: ...


#: Episodes held in memory (a list or tuple) or an on-disk store.
Episodes: TypeAlias = "list[Episode] | tuple[Episode, ...] | EpisodeStoreLike"


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

    def __init__(self, episodes: Episodes, indices: Sequence[int] | None = None) -> None:
        self.in_memory = isinstance(episodes, (list, tuple))
        self.episodes = episodes
        n = len(episodes) if isinstance(episodes, (list, tuple)) else len(episodes.episodes)
        self.indices = list(range(n)) if indices is None else list(indices)
        self.meta = [self._meta(i) for i in self.indices]

    def _meta(self, i: int) -> EpisodeMeta:
        if isinstance(self.episodes, (list, tuple)):  # in memory
            ep = self.episodes[i]
            return EpisodeMeta(ep.task, ep.instruction, dict(ep.object_names), list(ep.target_names), len(ep),
                               f"memory:{i}")
        store = self.episodes
        info = store.episodes[i]
        src: Any  # duck-typed: anything with task, instruction, object_names and target_names
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

    def positions(self, j: int) -> NDArray[np.float64]:
        """``(K, 3)`` keyframe target positions (m) of the ``j``-th selected episode."""
        if isinstance(self.episodes, (list, tuple)):  # in memory
            return np.array([a.position for _, a in self.episodes[self.indices[j]].steps]).reshape(-1, 3)
        if hasattr(self.episodes, "load_positions"):
            positions: NDArray[np.float64] = self.episodes.load_positions(self.indices[j])
            return positions
        return np.array([self.load_step(j, k)[1].position for k in range(self.meta[j].num_steps)]).reshape(-1, 3)

    def load_step(self, j: int, k: int) -> tuple[Observation, KeyframeAction]:
        """Observation and action of keyframe ``k`` of the ``j``-th selected episode."""
        if isinstance(self.episodes, (list, tuple)):  # in memory
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
    except (ImportError, OSError, KeyError, ValueError, AttributeError, TypeError):
        return None  # the caller reads the whole episode, whose reader names the file and what is wrong


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
            raise ConfigError("the dataset is empty: no keyframes match the selection")
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


class KeyframeDataset(Dataset[Sample]):
    """Policy-independent samples over a set of episodes (see module docstring and :mod:`abm.samples`).

    Args:
        source: the episodes (:class:`EpisodeSource`, a list of episodes or an ``EpisodeStore``).
        workspace: the policy's workspace cube (crop and augmentation bounds).
        grounder: grounder configuration (:mod:`abm.grounding.config`, or its dict form; default the oracle).
        split: split each instruction into the target X and the skill text.
        mask: compute the per-point mask field of X (implies ``split``).
        features: compute per-point CLIP features (needs a CLIP grounder and ``cache_dir``).
        destination: also compute the destination's mask field (the policy's second mask; implies ``split``).
        augment: apply SE(3) augmentation (translation ``max_translation`` m, yaw ``max_yaw_deg``).
        cache_dir: folder for cached grounding results / CLIP point features (needed for non-oracle
            grounders and ``features``).
        seed: base seed of the augmentation.
        camera_names: cameras to fuse (default all).
        require_cache: refuse to start when cache entries are missing (:func:`ground_keyframes` builds
            the dataset without it to fill them).
        memory_mb: memory (MiB, per data process) for keyframes kept fused and grounded after their first use:
            training draws each keyframe hundreds of times, and fusing the cameras and grounding is four
            fifths of a sample's cost; only the augmentation is redone. Keyframes past the budget are
            recomputed each time; 0 turns it off. Samples are identical either way.

    Items are indexed by ``(index, sample_seed)`` keys (see :class:`StepSampler`) or plain indices.
    """

    def __init__(
        self,
        source: EpisodeSource | Episodes,
        workspace: Workspace,
        grounder: GrounderConfig | Mapping[str, Any] | None = None,
        *,
        split: bool = True,
        mask: bool = False,
        features: bool = False,
        augment: bool = True,
        cache_dir: str | Path | None = None,
        seed: int = 0,
        camera_names: Sequence[str] | None = None,
        max_translation: float = 0.125,
        max_yaw_deg: float = 45.0,
        require_cache: bool = True,
        memory_mb: float = 2048.0,
        destination: bool = False,
    ) -> None:
        if memory_mb < 0:
            raise ConfigError(f"memory_mb must be >= 0 (0 turns the keyframe memory off), got {memory_mb}")
        self.memory_bytes = int(memory_mb * 2**20)
        self._memory: dict[int, _Remembered] = {}
        self._memory_used = 0
        self.source = source if isinstance(source, EpisodeSource) else EpisodeSource(source)
        self.grounder_config: GrounderConfig = as_grounder_config(grounder)
        self.split, self.mask, self.features = split or mask or destination, mask, features
        self.destination = destination
        self.augment = augment
        self.seed = seed
        self.camera_names = list(camera_names) if camera_names is not None else None
        self.max_translation, self.max_yaw_deg = max_translation, max_yaw_deg
        self.workspace = workspace
        self.fuse_workspace = augmentation_margin_cube(self.workspace, max_translation, max_yaw_deg) \
            if augment else self.workspace
        self.items = [(j, k) for j, m in enumerate(self.source.meta) for k in range(m.num_steps)]
        if not self.items:
            raise ConfigError("the dataset is empty: the selected episodes have no keyframes")
        self.check_inside_workspace()
        self.oracle = isinstance(self.grounder_config, OracleGrounderConfig)
        #: masks computed here, per sample (the oracle's), not read from the cache (the grounders whose kind is
        #: ``cached`` in :data:`abm.grounding.config.GROUNDERS`)
        self.live = not GROUNDERS[self.grounder_config.kind].cached
        # per-episode split of the instruction: the sub-goals' objects (X, or X and Y) and the skill text;
        # each keyframe grounds the active one (abm.grounding.conditioning.active_role)
        self.targets: list[str | tuple[str, ...] | None] = []
        self.skills: list[str | None] = []
        #: per episode, the destination's name (ground truth for the oracle, the instruction's words otherwise)
        self.destinations: list[str | None] = []
        for m in self.source.meta:
            target, skill, place = None, None, None
            if self.split:
                hint = m.target_names[0] if m.target_names else None
                roles, skill = split_roles(m.instruction, m.object_names, hint)
                if self.oracle and len(m.target_names) >= len(roles):
                    roles = tuple(m.target_names[: len(roles)])  # ground truth for the oracle; text for CLIP
                target = roles[0] if len(roles) == 1 else roles
                if destination:
                    known = self.oracle and m.task in TASKS and m.target_names
                    place = (TASKS[m.task].destination_name(m.target_names) if known
                             else instruction_destination(m.instruction, roles))
            self.targets.append(target)
            self.skills.append(skill)
            self.destinations.append(place)
        self._live_grounder: Grounder | None = None
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        if ((self.mask or self.destination) and not self.live) or self.features:
            if self.cache_dir is None:
                raise ValueError(
                    f"grounder {self.grounder_config.kind!r} (mask field or CLIP features) needs a cache_dir "
                    "for grounding results / CLIP features"
                )
            missing = len(self.missing_cache_entries())
            if missing and require_cache:
                raise DataError(
                    f"the grounding cache {self.cache_dir} lacks {missing} of {len(self.items)} keyframes for grounder "
                    f"{self.grounder_config.kind!r}: fill it first with `abm data ground` (abm train does this "
                    "itself before training). Entries are keyed by the grounder's options (e.g. the CLIP model), "
                    "the episode, the target, the cameras and the workspace cube (with augmentation's margin), "
                    "so these must match")

    def check_inside_workspace(self) -> None:
        """See :func:`check_inside_workspace`."""
        check_inside_workspace(self.source, self.workspace)

    # ------------------------------------------------------------------ caching
    @property
    def cached(self) -> bool:
        """Whether conditioning is read from the on-disk cache (cached grounders, CLIP features)."""
        return self.cache_dir is not None and (((self.mask or self.destination) and not self.live) or self.features)

    @functools.cached_property
    def _cache_grounder(self) -> dict[str, Any]:
        """The grounder part of every cache key, resolved once per dataset: the defaults the spec relies on and
        the CLIP's content digest, so retraining the CLIP in place during a training cannot change the keys."""
        spec = resolved_spec(self.grounder_config.to_dict())
        return {k: v for k, v in spec.items() if k not in ("device", "cache")}  # not results

    def _cache_file(self, j: int, k: int, destination: bool = False) -> Path:
        """The cache entry of keyframe ``k`` of episode ``j``: its target's mask field and CLIP features, or with
        ``destination`` its destination's mask field (keyed like a target of the destination's name: the same
        grounding of the same name shares one entry)."""
        assert self.cache_dir is not None
        meta = self.source.meta[j]
        target = self.destinations[j] if destination else self.targets[j] if self.mask else None  # features: none
        target_key = list(target) if isinstance(target, tuple) else target  # sub-goal objects: one entry per step
        what = {"grounder": self._cache_grounder, "target": target_key, "key": meta.key,
                "cameras": self.camera_names, "ws": [self.fuse_workspace.center, self.fuse_workspace.size]}
        digest = hashlib.sha1(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:16]
        return self.cache_dir / f"{digest}_k{k:03d}.npz"

    def _scene(self, j: int, obs: Observation, grounder: Grounder | None, mask: bool, features: bool,
               destination: bool = False) -> ConditionedCloud:
        meta = self.source.meta[j]
        return condition_cloud(obs, meta.instruction, self.fuse_workspace, grounder=grounder,
                               object_names=meta.object_names, split=False, target=self.targets[j],
                               skill=self.skills[j], mask=mask, features=features, camera_names=self.camera_names,
                               destination=destination, destination_name=self.destinations[j])

    def _cache_files(self, j: int, k: int) -> dict[str, Path]:
        """The cache entries keyframe ``k`` of episode ``j`` needs: ``"target"`` (mask field and / or CLIP
        features) and ``"destination"`` (a cached grounder's destination mask field, when it has a destination)."""
        files = {}
        if (self.mask and not self.live) or self.features:
            files["target"] = self._cache_file(j, k)
        if self.destination and not self.live and self.destinations[j] is not None:
            files["destination"] = self._cache_file(j, k, destination=True)
        return files

    def missing_cache_entries(self) -> list[tuple[int, int]]:
        """``(episode, keyframe)`` pairs whose grounding results are not in the cache yet."""
        if not self.cached:
            return []
        return [(j, k) for j, k in self.items if not all(p.exists() for p in self._cache_files(j, k).values())]

    def precompute(self, show_progress: bool = True) -> int:
        """Compute (in this process) and cache the missing grounding results and CLIP point features;
        returns how many keyframes were computed."""
        todo = self.missing_cache_entries()
        if not todo:
            return 0
        assert self.cache_dir is not None
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        grounder = build_grounder(self.grounder_config)
        bar = Progress(len(todo), "grounding keyframes", "keyframes", bar=show_progress)
        for j, k in todo:
            obs, _ = self.source.load_step(j, k)
            files = self._cache_files(j, k)
            if "target" in files and not files["target"].exists():
                scene = self._scene(j, obs, grounder, self.mask, self.features)
                arrays: dict[str, np.ndarray] = {}
                if scene.point_mask is not None:
                    arrays.update(mask=scene.point_mask.mask.astype(np.float16),
                                  heatmap=scene.point_mask.heatmap.astype(np.float16))
                if scene.features is not None:  # the patch rows the points use and each point's row
                    table = scene.features.compact()
                    arrays.update(feature_table=table.table.astype(np.float16),
                                  feature_row=table.index.astype(np.int32))
                _save_entry(files["target"], arrays)
            if "destination" in files and not files["destination"].exists():
                found = self._scene(j, obs, grounder, False, False, destination=True).destination_mask
                assert found is not None  # asked for
                _save_entry(files["destination"], {"mask": found.mask.astype(np.float16),
                                                   "heatmap": found.heatmap.astype(np.float16)})
            bar.update(1)
        bar.close()
        return len(todo)

    # ------------------------------------------------------------------ samples
    def __len__(self) -> int:
        return len(self.items)

    def _conditioned(self, j: int, k: int, obs: Observation) -> ConditionedCloud:
        if not self.cached:
            if (self.mask or self.destination) and self._live_grounder is None:
                self._live_grounder = build_grounder(self.grounder_config)  # a live one (checked when built)
            return self._scene(j, obs, self._live_grounder, self.mask, False, self.destination)
        files = self._cache_files(j, k)
        for path in files.values():
            if not path.exists():
                raise DataError(f"grounding cache entry {path} is missing; fill the cache with abm data ground")
        scene = self._scene(j, obs, None, False, False)
        pm, feats = None, None
        if "target" in files:
            with np.load(files["target"], allow_pickle=False) as data:
                pm = _point_mask(data) if self.mask else None
                feats = _cached_features(data) if self.features else None
        dest = None
        if self.destination:  # none declared: an empty mask, as condition_cloud gives
            empty = np.zeros(len(scene.cloud), np.float32)
            dest = PointMask(empty, empty.copy(), False)
            if "destination" in files:
                with np.load(files["destination"], allow_pickle=False) as data:
                    dest = _point_mask(data)
        return dataclasses.replace(scene, point_mask=pm, features=feats, destination=self.destinations[j],
                                   destination_mask=dest)

    def __getitem__(self, key: int | tuple[int, int]) -> Sample:
        index, sample_seed = (key, index_seed(key)) if isinstance(key, int) else key
        kept = self._memory.get(index)
        if kept is None:
            kept = self._remember(index)
        points, action, grip_pos = kept.points, kept.action, kept.gripper_position
        if self.augment:
            rng = np.random.default_rng([self.seed, sample_seed])
            points, action, transform = augment_cloud(points, action, self.workspace, rng,
                                                      self.max_translation, self.max_yaw_deg)
            grip_pos = transform_points(transform, grip_pos[None])[0]
        return cast(Sample, {**kept.sample, "points": torch.from_numpy(np.ascontiguousarray(points, np.float32)),
                             "gripper_position": torch.from_numpy(np.asarray(grip_pos, np.float32).reshape(3)),
                             **action_targets(action)})

    def _remember(self, index: int) -> _Remembered:
        """Load, fuse and ground one keyframe; keep it if the memory budget allows."""
        j, k = self.items[index]
        obs, action = self.source.load_step(j, k)
        scene = self._conditioned(j, k, obs)
        grip_pos = np.asarray(obs.gripper_pose[:3, 3], np.float64)
        # the parts of a sample that augmentation does not change (collate copies them into each batch)
        fixed = {key: value for key, value in cloud_sample(scene, obs.gripper_open, grip_pos,
                                                           keyframe_index=obs.step).items()
                 if key not in ("points", "gripper_position")}
        kept = _Remembered(fixed, np.ascontiguousarray(scene.cloud.xyz, np.float32), action, grip_pos)
        size = kept.points.nbytes + sum(v.untyped_storage().nbytes() for v in fixed.values()
                                        if isinstance(v, torch.Tensor))
        if self._memory_used + size <= self.memory_bytes:
            self._memory[index] = kept
            self._memory_used += size
        return kept


def _save_entry(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write one grounding cache entry (named arrays) atomically."""
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        np.savez(fh, **arrays)  # type: ignore[arg-type]  # numpy's stub confuses **arrays with allow_pickle


def _cached_features(data: Mapping[str, np.ndarray]) -> LiftedFeatures:
    """Cached CLIP point features (``feature_table`` float16 and ``feature_row`` int32; an entry written before
    tables, ``features`` ``(N, F)`` float16, gives one row per point) as :class:`LiftedFeatures`."""
    if "feature_table" in data:
        return LiftedFeatures(np.asarray(data["feature_table"]), np.asarray(data["feature_row"], np.int64))
    return LiftedFeatures.per_point(np.asarray(data["features"]))


def _point_mask(data: Mapping[str, np.ndarray]) -> PointMask:
    """A cached mask field (``mask``, ``heatmap`` as float16) as a :class:`PointMask`."""
    mask, heat = np.asarray(data["mask"], np.float32), np.asarray(data["heatmap"], np.float32)
    return PointMask(mask, heat, bool(mask.any()))


@dataclass(frozen=True)
class _Remembered:
    """One keyframe fused and grounded, before augmentation (see ``KeyframeDataset(memory_mb=...)``)."""

    sample: dict[str, Any]  # the sample entries augmentation leaves alone (colours, masks, features, texts)
    points: NDArray[np.float32]  # (N, 3) world metres
    action: KeyframeAction
    gripper_position: NDArray[np.float64]  # (3,) world metres


def check_inside_workspace(source: EpisodeSource, workspace: Workspace) -> None:
    """Refuse episodes whose keyframes lie outside the workspace cube: a policy could not point at them
    (their heatmap target would fall off the views). Reads only the keyframe positions."""
    outside = []
    for j, meta in enumerate(source.meta):
        pos = source.positions(j)
        bad = ~workspace.contains(pos)
        if bad.any():
            outside.append((meta, int(bad.sum()), pos[bad][0]))
    if outside:
        meta, count, where = outside[0]
        lo, hi = np.round(workspace.lower, 3).tolist(), np.round(workspace.upper, 3).tolist()
        raise ConfigError(
            f"{sum(c for _, c, _ in outside)} keyframes of {len(outside)} episodes lie outside the policy's "
            f"workspace cube {lo}..{hi} (m), e.g. {count} of {meta.task} episode {meta.key} such as "
            f"{np.round(where, 3).tolist()}; enlarge the cube (--workspace-size M --workspace-center X Y Z) or "
            "leave these tasks out")


def ground_keyframes(
    source: EpisodeSource | Episodes,
    workspace: Workspace,
    grounder: GrounderConfig | Mapping[str, Any],
    cache_dir: str | Path,
    *,
    mask: bool = True,
    features: bool = False,
    augment: bool = True,
    camera_names: Sequence[str] | None = None,
    show_progress: bool = True,
    destination: bool = False,
) -> int:
    """The explicit grounding step: run a cached grounder (its kind ``cached`` in
    :data:`abm.grounding.config.GROUNDERS`: CLIP) once over every keyframe and cache the
    per-point mask fields (``mask``; with ``destination`` the destination's too) and CLIP features (``features``)
    that a :class:`KeyframeDataset`
    with the same arguments reads. Resumable (existing entries are kept); returns how many keyframes
    were computed. A live grounder (the oracle) needs no cache (it returns 0)."""
    ds = KeyframeDataset(source, workspace, grounder, split=mask or destination, mask=mask, features=features,
                         augment=augment, cache_dir=cache_dir, camera_names=camera_names, require_cache=False,
                         destination=destination)
    return ds.precompute(show_progress)


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
