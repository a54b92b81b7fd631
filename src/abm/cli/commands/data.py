"""``abm data generate``, ``abm data ground`` and ``abm data info``."""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable
from typing import Any

from abm.data.episode_store import EpisodeInfo, EpisodeStore, verify_episode
from abm.data.formats import DATASET_FORMATS
from abm.data.generate import expand_tasks
from abm.data.stores import generate_tasks, ground_store
from abm.errors import ConfigError, ExternalError
from abm.geometry import Workspace
from abm.policy.config import PolicyConfig
from abm.registry import resolve


def _generate(args: argparse.Namespace) -> int:
    generate_tasks(expand_tasks(args.task), args.split, args.episodes, args.out, workers=args.workers, seed=args.seed,
                   resolution=args.resolution, splits_path=args.splits,
                   dense_fps=args.dense_fps if args.dense else None, backend=args.backend, ray_address=args.ray_address)
    return 0


def _format_function(name: str, which: str) -> tuple[Callable[..., Any], str]:
    """The writer or reader (``which``: ``export`` / ``import_``) of the format ``name``, and the advice for a
    missing dependency."""
    fmt = DATASET_FORMATS[name]
    advice = f"; install the {which.rstrip('_')} dependencies: pip install 'abm[{fmt.extra}]'" if fmt.extra else ""
    try:
        return resolve(getattr(fmt, which)), advice
    except ImportError as err:
        raise ExternalError(f"{err}{advice}") from None


def _export(args: argparse.Namespace) -> int:
    fmt = DATASET_FORMATS[args.format]
    # the formats' options (abm.data.formats.DatasetFormat.export_options) given on the command line
    options = {name: getattr(args, name) for name in args.format_options if getattr(args, name) is not None}
    foreign = sorted(set(options) - set(fmt.export_options))
    if foreign:
        flags = ", ".join("--" + name.replace("_", "-") for name in foreign)
        raise ConfigError(f"{flags}: not an option of --format {args.format} (it takes "
                          f"{', '.join('--' + n.replace('_', '-') for n in fmt.export_options) or 'none'})")
    export, advice = _format_function(args.format, "export")
    try:
        report = export(args.data, args.out, **options)
    except ImportError as err:
        raise ExternalError(f"{err}{advice}") from None
    print(report.summary(args.out))
    return 0


def _import(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out {args.out} is a file; give a folder")
    read, advice = _format_function(args.format, "import_")
    try:
        written = read(args.dataset, args.out, overwrite=args.overwrite, task=args.task, split=args.split)
    except ImportError as err:
        raise ExternalError(f"{err}{advice}") from None
    print(f"{len(written)} episodes -> {args.out}")
    return 0


def _info(args: argparse.Namespace) -> int:
    if not args.dir.is_dir():
        raise ConfigError(f"not a directory: {args.dir}")
    store = EpisodeStore(args.dir)
    groups: dict[tuple[str, str], list[EpisodeInfo]] = defaultdict(list)
    unchecked = 0
    for info in store.episodes:
        groups[(info.task, info.split)].append(info)
        if not args.quick:
            unchecked += not verify_episode(info.path)
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
    defaults = PolicyConfig()
    workspace = Workspace(tuple(args.workspace_center or defaults.workspace_center),
                          args.workspace_size or defaults.workspace_size)
    ground_store(args.data, args.cache, workspace, grounder=args.grounder, clip_model=args.clip_model,
                 clip_device=args.clip_device, features=args.features, tasks=args.tasks, splits=args.splits,
                 cameras=args.cameras, augment=not args.no_augment)
    return 0
