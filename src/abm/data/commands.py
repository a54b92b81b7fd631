"""``abm data generate``, ``abm data ground`` and ``abm data info``."""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

from abm.configuration import float_range, int_range, seed_int


def register(subparsers) -> None:
    from abm.configuration import CAMERA_RESOLUTION, WORKERS, clip_model_help
    from abm.ray_pool import add_backend_arguments

    data = subparsers.add_parser("data", help="generate and inspect demonstration episodes")
    sub = data.add_subparsers(dest="data_command", metavar="SUBCOMMAND")

    gen = sub.add_parser("generate", help="run the scripted expert and save demonstrations (resumable)")
    gen.add_argument("--task", required=True,
                     help="task name (e.g. place_food), a comma-separated list, or 'all' (every trainable "
                          "task; the evaluation-only compositional tasks are never generated)")
    gen.add_argument("--split", required=True, help="object split: seen or unseen")
    gen.add_argument("--episodes", type=int_range(1, 10**6), required=True, help="number of successful demonstrations")
    gen.add_argument("--out", required=True, type=Path, help="output directory")
    gen.add_argument("--workers", type=int_range(1, 256), default=WORKERS, help="parallel worker processes")
    gen.add_argument("--seed", type=seed_int, default=0, help="first scene seed")
    gen.add_argument("--resolution", type=int_range(16, 1024), default=CAMERA_RESOLUTION,
                     help="camera resolution (pixels, square)")
    gen.add_argument("--splits", type=Path, default=None, help="object split YAML replacing the default")
    gen.add_argument("--dense", action="store_true",
                     help="also record the full trajectory at a fixed control rate (camera frames, joint state, "
                          "joint and end-effector actions) for dense policies such as ACT or diffusion")
    gen.add_argument("--dense-fps", type=float_range(0.0, low_open=True), default=10.0,
                     help="control rate of --dense in frames per second (default 10; 1/fps must be a whole "
                          "number of 2 ms physics steps)")
    add_backend_arguments(gen)
    gen.set_defaults(func=_generate)

    export = sub.add_parser(
        "export", help="write abm episodes as a LeRobot v3 dataset (parquet + mp4)",
        description="Write every episode under --data as one LeRobot v3.0 dataset: meta/info.json, stats, "
        "tasks and episode parquet, frames as parquet (depth, segmentation and camera calibration lossless), "
        "camera streams as H.264 mp4. Dense episodes (generate --dense) export every control tick with "
        "joint actions; keyframe-only episodes export one frame per keyframe at a nominal 1 fps. The "
        "instruction is the task string; keyframe.is_keyframe flags the keyframes.")
    export.add_argument("--format", required=True, choices=["lerobot"], help="dataset format (lerobot: v3.0)")
    export.add_argument("--data", required=True, type=Path, help="folder of abm episodes")
    export.add_argument("--out", required=True, type=Path, help="new (or empty) dataset folder")
    export.add_argument("--frames", default="auto", choices=["auto", "dense", "keyframes"],
                        help="dense control ticks or keyframes only (auto: dense when every episode has them)")
    export.add_argument("--crf", type=int_range(0, 51), default=18, help="H.264 quality, 0 (best) to 51 (default 18)")
    export.set_defaults(func=_export)

    imp = sub.add_parser(
        "import", help="read a LeRobot v3 dataset written by abm data export back into abm episodes",
        description="Rebuild abm episode files (OUT/<task>/<split>/episode_<seed>.h5) from a LeRobot v3.0 "
        "dataset written by `abm data export`: keyframes, dense trajectories, depth, segmentation and "
        "calibration come back exactly, camera images within the video codec's tolerance.")
    imp.add_argument("dataset", type=Path, help="LeRobot dataset folder")
    imp.add_argument("--format", required=True, choices=["lerobot"], help="dataset format (lerobot: v3.0)")
    imp.add_argument("--out", required=True, type=Path, help="output folder of abm episodes")
    imp.set_defaults(func=_import)

    ground = sub.add_parser(
        "ground", help="run a CLIP grounder once over every keyframe and cache the results for training",
        description="The explicit grounding step of training with a learned grounder: the per-point mask "
        "field of each keyframe's target (or, with --features, the per-point CLIP features of the ifd "
        "baseline) is computed once and cached. Train with the same --cameras / workspace / --no-augment "
        "and `abm train --cache-dir CACHE` (abm train also fills missing entries itself). Resumable.")
    ground.add_argument("--data", required=True, type=Path, help="episode store folder")
    ground.add_argument("--cache", required=True, type=Path, help="cache folder (abm train --cache-dir)")
    ground.add_argument("--grounder", default="clip", choices=["clip"], help="grounder (the oracle needs no cache)")
    ground.add_argument("--clip-model", help=clip_model_help("of the grounder"))
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
    info.add_argument("dir", type=Path, help="episode folder (abm data generate --out)")
    info.add_argument("--quick", action="store_true",
                      help="read metadata only (default: read every dataset and check its checksum)")
    info.set_defaults(func=_info)
    data.set_defaults(func=lambda args: data.print_help() or 1)


def _generate(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.data.generate import EvaluationOnlyTaskError, expand_tasks, generate
    from abm.ray_pool import RayBackendError
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
    if args.dense:
        from abm.sim.recorder import control_period

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
    from abm.cli import CommandError
    from abm.data.episode_store import EpisodeFormatError
    from abm.data.lerobot import export_lerobot, remove_partial

    try:
        report = export_lerobot(args.data, args.out, frames=args.frames, crf=args.crf)
    except ImportError as err:
        raise CommandError(f"{err}; install the export dependencies: pip install 'abm[lerobot]'") from None
    except (EpisodeFormatError, ValueError, FileNotFoundError) as err:
        remove_partial(args.out)
        raise CommandError(str(err)) from None
    kind = f"dense frames at {report.fps:g} fps" if report.dense else "keyframes (nominal 1 fps)"
    print(f"{report.episodes} episodes, {report.frames} {kind} -> {args.out} (LeRobot v3.0, "
          f"{report.bytes / 1e6:.1f} MB)")
    return 0


def _import(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.data.lerobot import import_lerobot

    if args.out.exists() and not args.out.is_dir():
        raise CommandError(f"--out {args.out} is a file; give a folder")
    try:
        written = import_lerobot(args.dataset, args.out)
    except ImportError as err:
        raise CommandError(f"{err}; install the import dependencies: pip install 'abm[lerobot]'") from None
    except (ValueError, FileNotFoundError) as err:
        raise CommandError(str(err)) from None
    print(f"{len(written)} episodes -> {args.out}")
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
    from abm.grounding.config import grounder_config_from_dict

    grounder = grounder_config_from_dict(
        {"kind": args.grounder, **{k: v for k, v in (("model", args.clip_model), ("device", args.clip_device)) if v}})
    made = ground_keyframes(EpisodeSource(store, indices), workspace, grounder, args.cache, mask=not args.features,
                            features=args.features, augment=not args.no_augment, camera_names=args.cameras)
    what = "CLIP point features" if args.features else "mask fields"
    print(f"{what} of {made} keyframes computed ({len(indices)} episodes) -> {args.cache}")
    return 0
