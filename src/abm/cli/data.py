"""``abm data generate``, ``abm data ground`` and ``abm data info``.

These parsers are written by hand, not generated from a config dataclass (abm.configuration) like the other
commands': they use what add_config_arguments cannot express without changing the flags or their help —
positional arguments (``abm data info DIR``, ``abm data import DATASET``), ``--workspace-center X Y Z``'s
metavar, ``--dense-fps``'s open lower bound, ``--clip-model``'s computed help, ``--backend``/``--ray-address``
from abm.ray_pool. Every option still has a checked range type and a help text (tests/test_cli_help.py,
tests/test_fuzz.py).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import CAMERA_RESOLUTION, SPLITS, WORKERS, clip_model_help, float_range, int_range, seed_int
from abm.data.formats import DATASET_FORMATS
from abm.grounding.config import GROUNDERS
from abm.ray_pool import add_backend_arguments


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    gen.set_defaults(func="abm.cli.commands.data:_generate")

    formats = DATASET_FORMATS.names()
    format_help = "dataset format: " + "; ".join(f"{name}: {DATASET_FORMATS[name].description}" for name in formats)
    export = sub.add_parser(
        "export", help="write abm episodes as a dataset of another format (LeRobot v3: parquet + mp4)",
        description="Write every episode under --data as one LeRobot v3.0 dataset: meta/info.json, stats, "
        "tasks and episode parquet, frames as parquet (depth, segmentation and camera calibration lossless), "
        "camera streams as H.264 mp4. Dense episodes (generate --dense) export every control tick at the "
        "recording rate with joint actions; keyframe exports have one frame per keyframe (info.json "
        "frame_sampling: keyframes, images as PNG in the parquet, fps only an index step). Depth, segmentation "
        "and calibration are geometry.* columns, which LeRobot policies do not read as state. The instruction is "
        "the task string; keyframe.is_keyframe flags the keyframes.")
    export.add_argument("--format", required=True, choices=formats, help=format_help)
    export.add_argument("--data", required=True, type=Path, help="folder of abm episodes")
    export.add_argument("--out", required=True, type=Path, help="new (or empty) dataset folder")
    # the options of one format (DatasetFormat.export_options): not given, the format's own default holds
    options = (
        export.add_argument("--frames", choices=["auto", "dense", "keyframes"],
                            help="lerobot: dense control ticks or keyframes only (default auto: dense when every "
                                 "episode has them)"),
        export.add_argument("--crf", type=int_range(0, 51), help="lerobot: H.264 quality, 0 (best) to 51 (default 18)"),
        export.add_argument("--data-file-mb", type=float_range(0.0, low_open=True),
                            help="lerobot: size limit of a frame parquet file in MiB, LeRobot's "
                                 "data_files_size_in_mb (default 100)"),
        export.add_argument("--video-file-mb", type=float_range(0.0, low_open=True),
                            help="lerobot: size limit of an mp4 file in MiB, LeRobot's video_files_size_in_mb "
                                 "(default 200)"),
    )
    export.set_defaults(func="abm.cli.commands.data:_export", format_options=tuple(a.dest for a in options))

    imp = sub.add_parser(
        "import", help="read a dataset of another format (LeRobot v3: abm's own export, or another with depth and "
        "calibration) into abm episodes",
        description="Rebuild abm episode files (OUT/<task>/<split>/episode_<N>.h5) from a LeRobot v3.0 "
        "dataset. One written by `abm data export` comes back as exported: keyframes, dense trajectories, depth, "
        "segmentation and calibration exactly, camera images within the video codec's tolerance (exactly for "
        "keyframe exports); its files are checked against the checksums the export recorded, and episodes marked "
        "failed, of unknown tasks or named outside --out are refused, before anything is written. Another LeRobot "
        "dataset needs, per camera, geometry.depth.<camera>, geometry.intrinsics.<camera> and "
        "geometry.extrinsics.<camera>, the gripper pose and opening in observation.state, and --task; its "
        "keyframes are detected (docs/datasets.md).")
    imp.add_argument("dataset", type=Path, help="dataset folder")
    imp.add_argument("--format", required=True, choices=formats, help=format_help)
    imp.add_argument("--out", required=True, type=Path, help="output folder of abm episodes")
    imp.add_argument("--task", help="ABM-Bench task the episodes show, for a dataset not written by abm (abm's own "
                     "exports name theirs)")
    imp.add_argument("--split", choices=list(SPLITS),
                     help="split of the episodes of a dataset not written by abm (default: seen)")
    imp.add_argument("--overwrite", action="store_true",
                     help="replace episode files --out already holds (and finish an import that did not finish); "
                     "without it such an import is refused before anything is written")
    imp.set_defaults(func="abm.cli.commands.data:_import")

    ground = sub.add_parser(
        "ground", help="run a CLIP grounder once over every keyframe and cache the results for training",
        description="The explicit grounding step of training with a learned grounder: the per-point mask "
        "field of each keyframe's target (or, with --features, the per-point CLIP features of the ifd "
        "baseline) is computed once and cached. Train with the same --cameras / workspace / --no-augment "
        "and `abm train --cache-dir CACHE` (abm train also fills missing entries itself). Resumable.")
    ground.add_argument("--data", required=True, type=Path, help="episode store folder")
    ground.add_argument("--cache", required=True, type=Path, help="cache folder (abm train --cache-dir)")
    cached = GROUNDERS.names(cached=True)  # the others ground each sample as it is drawn (the oracle)
    ground.add_argument("--grounder", default=cached[0], choices=cached,
                        help="grounder whose results are cached for training (the oracle needs no cache)")
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
    ground.set_defaults(func="abm.cli.commands.data:_ground")

    info = sub.add_parser("info", help="summarise the episodes in a directory")
    info.add_argument("dir", type=Path, help="episode folder (abm data generate --out)")
    info.add_argument("--quick", action="store_true",
                      help="read metadata only (default: read every dataset and check its checksum)")
    info.set_defaults(func="abm.cli.commands.data:_info")

    def usage(args: argparse.Namespace) -> int:  # the group without a sub-command
        data.print_help()
        return 1

    data.set_defaults(func=usage)
