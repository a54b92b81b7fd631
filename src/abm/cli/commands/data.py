"""``abm data generate``, ``abm data ground`` and ``abm data info``."""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable
from typing import Any

from abm.cli import CommandError
from abm.data.episode_store import EpisodeFormatError, EpisodeStore, verify_episode
from abm.data.formats import DATASET_FORMATS
from abm.data.generate import EvaluationOnlyTaskError, expand_tasks, generate
from abm.data.keyframes import EpisodeSource, ground_keyframes
from abm.geometry import Workspace
from abm.grounding.config import grounder_from_flags
from abm.policy.config import PolicyConfig
from abm.ray_pool import RayBackendError
from abm.registry import resolve
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


def _format_function(name: str, which: str) -> tuple[Callable[..., Any], str]:
    """The writer or reader (``which``: ``export`` / ``import_``) of the format ``name``, and the advice for a
    missing dependency."""
    fmt = DATASET_FORMATS[name]
    advice = f"; install the {which.rstrip('_')} dependencies: pip install 'abm[{fmt.extra}]'" if fmt.extra else ""
    try:
        return resolve(getattr(fmt, which)), advice
    except ImportError as err:
        raise CommandError(f"{err}{advice}") from None


def _export(args: argparse.Namespace) -> int:
    fmt = DATASET_FORMATS[args.format]
    # the formats' options (abm.data.formats.DatasetFormat.export_options) given on the command line
    options = {name: getattr(args, name) for name in args.format_options if getattr(args, name) is not None}
    foreign = sorted(set(options) - set(fmt.export_options))
    if foreign:
        flags = ", ".join("--" + name.replace("_", "-") for name in foreign)
        raise CommandError(f"{flags}: not an option of --format {args.format} (it takes "
                           f"{', '.join('--' + n.replace('_', '-') for n in fmt.export_options) or 'none'})")
    export, advice = _format_function(args.format, "export")
    try:
        report = export(args.data, args.out, **options)
    except ImportError as err:
        raise CommandError(f"{err}{advice}") from None
    except (EpisodeFormatError, ValueError, FileNotFoundError) as err:  # the export removed what it wrote
        raise CommandError(str(err)) from None
    print(report.summary(args.out))
    return 0


def _import(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.out.is_dir():
        raise CommandError(f"--out {args.out} is a file; give a folder")
    read, advice = _format_function(args.format, "import_")
    try:
        written = read(args.dataset, args.out, overwrite=args.overwrite, task=args.task, split=args.split)
    except ImportError as err:
        raise CommandError(f"{err}{advice}") from None
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
