"""``abm run`` (a trained policy on a recorded, simulated or dry-run robot) and ``abm calibrate``
(hand-eye calibration of a fixed camera with a gripper-mounted ChArUco board)."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli.robot import parse_board_text
from abm.errors import ConfigError, OutputError, RefusedError
from abm.files import refuse_links
from abm.grounding.config import grounder_from_flags
from abm.policy import KeyframePolicy
from abm.robot.calibration import BoardSpec, calibrate_from_recording, load_calibration, save_calibration
from abm.robot.devices import record_observations
from abm.robot.run import RobotConfig, run_robot


def parse_board(text: str) -> BoardSpec:
    """``"5x7:0.04:0.03:DICT_4X4_50"`` -> :class:`abm.robot.calibration.BoardSpec`."""
    try:
        squares, square, marker, dictionary = parse_board_text(text)
    except argparse.ArgumentTypeError as err:
        raise ConfigError(f"--board {err}") from None
    return BoardSpec(squares, square, marker, dictionary)


def calibrate(args: argparse.Namespace) -> int:
    spec = parse_board(args.board)
    intrinsics, extrinsics, stats = calibrate_from_recording(args.recording, args.camera, spec)
    cameras = load_calibration(args.out) if args.out.is_file() else {}
    cameras[args.camera] = {"intrinsics": intrinsics, "extrinsics": extrinsics}
    save_calibration(args.out, cameras)
    print(f"abm calibrate: {args.camera} from {stats['views']} views (reprojection {stats['reprojection_px']:.2f} px)"
          f" -> {args.out}")
    return 0


RECORDING_FILES = ("meta.json", "step_*.npz")  # what abm.robot.record_observations writes into a folder


def check_record_target(out: Path, overwrite: bool) -> list[Path]:
    """The recording files ``abm record --out OUT`` replaces (empty for a new or empty folder).

    Raises:
        OutputError: ``out`` is a file, a recording file in it is a symbolic link, or ``out`` holds anything
            and ``overwrite`` is not set (nothing is written before this check).
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out} is a file; give a folder")
    if not out.is_dir():
        return []
    refuse_links(out, RECORDING_FILES, fix="remove the link, or record into a new --out folder")
    old = sorted(p for pattern in RECORDING_FILES for p in out.glob(pattern))
    if not overwrite and any(out.iterdir()):
        held = f"a recording ({len(old)} files, e.g. {old[0]})" if old else "other files"
        raise OutputError(f"--out {out} already holds {held}; pass --overwrite to replace the recording, or "
                          "record into a new folder")
    return old


def run_record(args: argparse.Namespace) -> int:
    from abm.sim.env import TaskEnv, run_expert  # mujoco (optional `sim` extra): `abm run`/`calibrate` need none

    old = check_record_target(args.out, args.overwrite)  # before the expert runs: it takes a while
    with TaskEnv(args.task, args.split, args.seed, resolution=args.resolution) as env:
        episode = run_expert(env)
    for path in old:  # --overwrite: the old recording goes (a longer one would leave its last steps behind)
        path.unlink(missing_ok=True)
    record_observations([obs for obs, _ in episode.steps], args.out, episode.object_names, episode.instruction)
    print(f"abm record: {len(episode.steps)} frames of {episode.instruction!r} -> {args.out} (replay it with "
          f"cameras: {{kind: replay, path: {args.out}}}, e.g. examples/robot_replay.yaml)")
    return 0


def run(args: argparse.Namespace) -> int:
    if not args.robot.is_file():
        raise ConfigError(f"--robot {args.robot} is not a file")
    if args.steps < 1:
        raise ConfigError("--steps must be at least 1")
    grounder = grounder_from_flags(args.grounder, args.clip_model)
    if args.instruction is not None and not args.instruction.strip():
        raise ConfigError("--instruction is empty; give the instruction to carry out, naming one object of the "
                          "scene (e.g. --instruction 'put the red block on the target'), or leave the option out "
                          "to use the recording's or the scene's")
    config = RobotConfig.load(args.robot)
    camera, arm = config.build(dry_run=args.dry_run)
    instruction = args.instruction if args.instruction is not None else getattr(camera, "instruction", "")
    if not instruction or not instruction.strip():
        raise ConfigError(f"give --instruction: the camera source of {args.robot} "
                          f"(kind {config.cameras.get('kind')}) has no instruction")
    policy = KeyframePolicy.from_checkpoint(args.run, device=args.device, grounder=grounder)
    try:
        records = run_robot(policy, camera, arm, instruction, config.limits, args.steps, args.log,
                            allow_no_target=args.allow_no_target)
    except RefusedError as err:
        raise RefusedError(f"refused before moving: {err} (log: {args.log})") from None
    finally:
        if hasattr(camera, "close"):
            camera.close()
    done = " (task succeeded)" if records and records[-1].get("success") else ""
    print(f"abm run: {len(records)} keyframes{done}; log: {args.log / 'steps.jsonl'}")
    return 0
