"""Fill an episode store and ground its keyframes: what ``abm data generate`` and ``abm data ground`` run, and the
experiment engine's data and ground jobs (:mod:`abm.experiments.jobs`) call the same two functions.

::

    generate_tasks(["pick_block", "place_food"], "seen", 20, Path("runs/x/data"), workers=2)
    ground_store(Path("runs/x/data"), Path("runs/x/cache_masks"), Workspace((0.5, 0.0, 0.15), 0.6),
                 grounder="clip", clip_model="models/benchmark-clip", tasks=["pick_block"])
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from abm.configuration import CAMERA_RESOLUTION
from abm.data.episode_store import EpisodeStore
from abm.data.generate import generate
from abm.data.keyframes import EpisodeSource, ground_keyframes
from abm.errors import ConfigError
from abm.geometry import Workspace
from abm.grounding.config import GROUNDERS, grounder_from_flags
from abm.sim.recorder import control_period


def generate_tasks(tasks: Sequence[str], split: str, episodes: int, out: Path, *, workers: int = 1, seed: int = 0,
                   resolution: int = CAMERA_RESOLUTION, splits_path: Path | None = None,
                   dense_fps: float | None = None, backend: str = "local", ray_address: str | None = None) -> None:
    """Make sure ``episodes`` successful demonstrations of each task exist in the store ``out`` (resumable: what is
    there is kept), printing one line per task (new, present, expert failures, time).

    Args:
        tasks: task names (``all`` already expanded: :func:`abm.data.generate.expand_tasks`).
        split: object split (``seen``, ``unseen``).
        episodes: demonstrations per task, at least 1.
        out: the store's folder.
        workers: simulator processes (or Ray actors), at least 1.
        seed: the first scene seed.
        resolution: camera resolution in pixels, 16 to 1024.
        splits_path: object split file replacing the built-in one.
        dense_fps: also record the full trajectory at this control rate (Hz); ``None``: keyframes only.
        backend: ``local`` processes or ``ray`` actors (at ``ray_address``, else a local Ray).

    Raises:
        ConfigError: a count or resolution out of range, ``out`` a file, or a control rate the simulator lacks.
    """
    if episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, got {episodes}")
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if not 16 <= resolution <= 1024:
        raise ConfigError(f"--resolution must be between 16 and 1024, got {resolution}")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} is a file; give a folder")
    if dense_fps is not None:
        control_period(dense_fps)  # a ConfigError naming the allowed rates
    for task in tasks:
        report = generate(task, split, episodes, out, workers=workers, seed=seed, resolution=resolution,
                          splits_path=splits_path, dense_fps=dense_fps, backend=backend, ray_address=ray_address)
        print(f"{task}/{split}: {report.created} new, {report.skipped} already present, "
              f"{len(report.failed_seeds)} expert failures, {report.seconds:.0f} s "
              f"({report.episodes_per_minute:.1f} episodes/min) -> {out}")


def ground_store(data: Path, cache: Path, workspace: Workspace, *, grounder: str = GROUNDERS.names(cached=True)[0],
                 clip_model: str | None = None, clip_device: str | None = None, features: bool = False,
                 tasks: Sequence[str] | None = None, splits: Sequence[str] = ("seen",),
                 cameras: Sequence[str] | None = None, augment: bool = True) -> int:
    """Ground every keyframe of the store ``data`` once with a cached grounder (CLIP) and write the per-point mask
    fields (or, with ``features``, the CLIP point features of the ifd baseline) into ``cache``, where a training
    with the same workspace, cameras and augmentation reads them; resumable. Prints one line; returns how many
    keyframes were computed.

    Args:
        workspace: the policy's workspace cube (its centre and edge in m).
        tasks: the tasks (``None``: every task of the store); ``splits``: the splits.
        cameras: the cameras to fuse (``None``: all).
        augment: ``False`` for a training with ``--no-augment`` (a smaller crop).

    Raises:
        ConfigError: ``data`` not a folder, ``cache`` a file, nothing selected, or episodes that disagree.
    """
    if not data.is_dir():
        raise ConfigError(f"--data {data} is not a folder")
    if cache.exists() and not cache.is_dir():
        raise ConfigError(f"--cache {cache} is a file; give a folder")
    store = EpisodeStore(data)
    chosen = None if tasks is None else list(tasks)
    indices = store.select(tasks=chosen, splits=list(splits))
    if not indices:
        raise ConfigError(store.nothing_selected(chosen, list(splits)))
    store.check_consistent(indices)
    config = grounder_from_flags(grounder, clip_model, clip_device)
    assert config is not None  # a kind is given
    made = ground_keyframes(EpisodeSource(store, indices), workspace, config, cache, mask=not features,
                            features=features, augment=augment, camera_names=cameras)
    what = "CLIP point features" if features else "mask fields"
    print(f"{what} of {made} keyframes computed ({len(indices)} episodes) -> {cache}")
    return made
