"""``abm data generate``, ``abm data ground`` and ``abm data info``."""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

from abm.configuration import float_range, int_range, seed_int


def register(subparsers) -> None:
    data = subparsers.add_parser("data", help="generate and inspect demonstration episodes")
    sub = data.add_subparsers(dest="data_command", metavar="SUBCOMMAND")

    gen = sub.add_parser("generate", help="run the scripted expert and save demonstrations (resumable)")
    gen.add_argument("--task", required=True,
                     help="task name (e.g. place_food), a comma-separated list, or 'all' (every trainable "
                          "task; the evaluation-only compositional tasks are never generated)")
    gen.add_argument("--split", required=True, help="object split: seen or unseen")
    gen.add_argument("--episodes", type=int_range(1, 10**6), required=True, help="number of successful demonstrations")
    gen.add_argument("--out", required=True, type=Path, help="output directory")
    gen.add_argument("--workers", type=int_range(1, 256), default=1, help="parallel worker processes")
    gen.add_argument("--seed", type=seed_int, default=0, help="first scene seed")
    gen.add_argument("--resolution", type=int_range(16, 1024), default=128, help="camera resolution (pixels, square)")
    gen.add_argument("--splits", type=Path, default=None, help="object split YAML replacing the default")
    gen.set_defaults(func=_generate)

    ground = sub.add_parser(
        "ground", help="run a CLIP grounder once over every keyframe and cache the results for training",
        description="The explicit grounding step of training with a learned grounder: the per-point mask "
        "field of each keyframe's target (or, with --features, the per-point CLIP features of the ifd "
        "baseline) is computed once and cached. Train with the same --cameras / workspace / --no-augment "
        "and `abm train --cache-dir CACHE` (abm train also fills missing entries itself). Resumable.")
    ground.add_argument("--data", required=True, type=Path, help="episode store folder")
    ground.add_argument("--cache", required=True, type=Path, help="cache folder (abm train --cache-dir)")
    ground.add_argument("--grounder", default="clip", choices=["clip"], help="grounder (the oracle needs no cache)")
    ground.add_argument("--clip-model", help="CLIP weights: hub name, local folder, or 'tiny' (tests only)")
    ground.add_argument("--clip-device", help="device of the CLIP model (default: CUDA when available)")
    ground.add_argument("--features", action="store_true",
                        help="cache CLIP point features (ifd) instead of the target's mask field")
    ground.add_argument("--tasks", nargs="+", help="tasks (default: all in the store)")
    ground.add_argument("--splits", nargs="+", default=["seen"], help="splits (default: seen)")
    ground.add_argument("--cameras", nargs="+", help="cameras to fuse (default: all)")
    ground.add_argument("--workspace-center", nargs=3, type=float_range(None), metavar=("X", "Y", "Z"),
                        help="the policy's workspace cube centre in m (default: the policy default)")
    ground.add_argument("--workspace-size", type=float_range(0.0, low_open=True),
                        help="the cube's edge in m (default: the policy default)")
    ground.add_argument("--no-augment", action="store_true", help="for training with --no-augment (smaller crop)")
    ground.set_defaults(func=_ground)

    info = sub.add_parser("info", help="summarise the episodes in a directory")
    info.add_argument("dir", type=Path)
    info.add_argument("--quick", action="store_true",
                      help="read metadata only (default: read every dataset and check its checksum)")
    info.set_defaults(func=_info)
    data.set_defaults(func=lambda args: data.print_help() or 1)


def _generate(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.data.generate import EvaluationOnlyTaskError, expand_tasks, generate
    from abm.sim.assets import AssetNotFoundError
    from abm.sim.splits import SplitFileError

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
    for task in tasks:
        try:
            report = generate(task, args.split, args.episodes, args.out, workers=args.workers,
                              seed=args.seed, resolution=args.resolution, splits_path=args.splits)
        except (SplitFileError, AssetNotFoundError) as err:
            raise CommandError(str(err)) from None
        print(f"{task}/{args.split}: {report.created} new, {report.skipped} already present, "
              f"{len(report.failed_seeds)} expert failures, {report.seconds:.0f} s "
              f"({report.episodes_per_minute:.1f} episodes/min) -> {args.out}")
    return 0


def _info(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.data.episode_store import EpisodeFormatError, EpisodeStore, verify_episode

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
    from abm.cli import CommandError
    from abm.data.episode_store import EpisodeFormatError, EpisodeStore
    from abm.data.keyframes import EpisodeSource, ground_keyframes
    from abm.geometry import Workspace
    from abm.policy.config import PolicyConfig

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
            raise CommandError(f"no episodes in {args.data} for tasks {args.tasks or 'any'} and splits {args.splits}")
        store.check_consistent(indices)
    except EpisodeFormatError as err:
        raise CommandError(str(err)) from None
    spec = {"kind": args.grounder, **{k: v for k, v in (("model", args.clip_model), ("device", args.clip_device)) if v}}
    made = ground_keyframes(EpisodeSource(store, indices), workspace, spec, args.cache, mask=not args.features,
                            features=args.features, augment=not args.no_augment, camera_names=args.cameras)
    what = "CLIP point features" if args.features else "mask fields"
    print(f"{what} of {made} keyframes computed ({len(indices)} episodes) -> {args.cache}")
    return 0
