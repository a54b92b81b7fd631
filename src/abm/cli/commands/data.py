"""``abm data generate``, ``abm data ground`` and ``abm data info``."""

from __future__ import annotations

import argparse
from collections import defaultdict

from abm.cli import CommandError
from abm.data.episode_store import EpisodeFormatError, EpisodeStore, verify_episode
from abm.data.generate import EvaluationOnlyTaskError, expand_tasks, generate
from abm.data.keyframes import EpisodeSource, ground_keyframes
from abm.data.lerobot import export_lerobot, import_lerobot
from abm.geometry import Workspace
from abm.grounding.config import grounder_from_flags
from abm.policy.config import PolicyConfig
from abm.ray_pool import RayBackendError
from abm.sim.assets import AssetNotFoundError
from abm.sim.recorder import control_period
from abm.sim.splits import SplitFileError


def _generate(args: argparse.Namespace) -> int:
    try:
        tasks = expand_tasks(args.task)
    except KeyError as err:
        raise CommandError(str(err.args[0])) from None
    except EvaluationOnlyTaskError as err:
        raise CommandError(str(err)) from None
    if args.episodes < 1:
        raise CommandError(f"--episodes must be at least 1, got {args.episodes}")
    if args.workers < 1:
        raise CommandError(f"--workers must be at least 1, got {args.workers}")
    if not 16 <= args.resolution <= 1024:
        raise CommandError(f"--resolution must be between 16 and 1024, got {args.resolution}")
    if args.out.exists() and not args.out.is_dir():
        raise CommandError(f"--out {args.out} is a file; give a folder")
    if args.dense:
        control_period(args.dense_fps)  # ValueError with the allowed rates
    for task in tasks:
        try:
            report = generate(task, args.split, args.episodes, args.out, workers=args.workers,
                              seed=args.seed, resolution=args.resolution, splits_path=args.splits,
                              dense_fps=args.dense_fps if args.dense else None, backend=args.backend,
                              ray_address=args.ray_address)
        except (SplitFileError, AssetNotFoundError, RayBackendError) as err:
            raise CommandError(str(err)) from None
        print(f"{task}/{args.split}: {report.created} new, {report.skipped} already present, "
              f"{len(report.failed_seeds)} expert failures, {report.seconds:.0f} s "
              f"({report.episodes_per_minute:.1f} episodes/min) -> {args.out}")
    return 0


def _export(args: argparse.Namespace) -> int:
    try:
        report = export_lerobot(args.data, args.out, frames=args.frames, crf=args.crf,
                                data_file_mb=args.data_file_mb, video_file_mb=args.video_file_mb)
    except ImportError as err:
        raise CommandError(f"{err}; install the export dependencies: pip install 'abm[lerobot]'") from None
    except (EpisodeFormatError, ValueError, FileNotFoundError) as err:  # the export removed what it wrote
        raise CommandError(str(err)) from None
    kind = f"dense frames at {report.fps:g} fps" if report.dense else "keyframes (one frame per keyframe)"
    print(f"{report.episodes} episodes, {report.frames} {kind} -> {args.out} (LeRobot v3.0, "
          f"{_files(report.files)}, {report.bytes / 1e6:.1f} MB)")
    return 0


def _files(names: list[str]) -> str:
    """"2 data files, 4 video files" of an export's file names."""
    data = sum(name.startswith("data/") for name in names)
    videos = len(names) - data
    return f"{data} data file{'s' * (data != 1)}" + (f", {videos} video file{'s' * (videos != 1)}" if videos else "")


def _import(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.out.is_dir():
        raise CommandError(f"--out {args.out} is a file; give a folder")
    try:
        written = import_lerobot(args.dataset, args.out, overwrite=args.overwrite, task=args.task, split=args.split)
    except ImportError as err:
        raise CommandError(f"{err}; install the import dependencies: pip install 'abm[lerobot]'") from None
    except (ValueError, FileNotFoundError) as err:
        raise CommandError(str(err)) from None
    print(f"{len(written)} episodes -> {args.out}")
    return 0


def _info(args: argparse.Namespace) -> int:
    if not args.dir.is_dir():
        raise CommandError(f"not a directory: {args.dir}")
    try:
        store = EpisodeStore(args.dir)
    except EpisodeFormatError as err:
        raise CommandError(str(err)) from None
    groups: dict[tuple[str, str], list] = defaultdict(list)
    unchecked = 0
    for info in store.episodes:
        groups[(info.task, info.split)].append(info)
        if not args.quick:
            try:
                unchecked += not verify_episode(info.path)
            except EpisodeFormatError as err:
                raise CommandError(str(err)) from None
    total_bytes = sum(info.path.stat().st_size for info in store.episodes)
    print(f"{args.dir}: {len(store)} episodes, {total_bytes / 1e6:.1f} MB")
    if not groups:
        return 0
    print(f"{'task':<16}{'split':<14}{'episodes':>9}{'success':>9}{'keyframes':>11}{'MB':>9}")
    for (task, split), infos in sorted(groups.items()):
        size = sum(i.path.stat().st_size for i in infos) / 1e6
        keyframes = sum(i.num_keyframes for i in infos)
        ok = sum(i.success for i in infos)
        print(f"{task:<16}{split:<14}{len(infos):>9}{ok:>9}{keyframes:>11}{size:>9.1f}")
    if args.quick:
        print("metadata only (--quick): the image and action data were not checked")
    else:
        print("every dataset read back and checked against its checksum"
              + (f" ({unchecked} episode(s) written without checksums were only read)" if unchecked else ""))
    return 0


def _ground(args: argparse.Namespace) -> int:
    if not args.data.is_dir():
        raise CommandError(f"--data {args.data} is not a folder")
    if args.cache.exists() and not args.cache.is_dir():
        raise CommandError(f"--cache {args.cache} is a file; give a folder")
    defaults = PolicyConfig()
    workspace = Workspace(tuple(args.workspace_center or defaults.workspace_center),
                          args.workspace_size or defaults.workspace_size)
    try:
        store = EpisodeStore(args.data)
        indices = store.select(tasks=args.tasks, splits=args.splits)
        if not indices:
            raise CommandError(store.nothing_selected(args.tasks, args.splits))
        store.check_consistent(indices)
    except EpisodeFormatError as err:
        raise CommandError(str(err)) from None
    grounder = grounder_from_flags(args.grounder, args.clip_model, args.clip_device)
    made = ground_keyframes(EpisodeSource(store, indices), workspace, grounder, args.cache, mask=not args.features,
                            features=args.features, augment=not args.no_augment, camera_names=args.cameras)
    what = "CLIP point features" if args.features else "mask fields"
    print(f"{what} of {made} keyframes computed ({len(indices)} episodes) -> {args.cache}")
    return 0
