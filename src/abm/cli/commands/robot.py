"""``abm run`` (a trained policy on a recorded, simulated or dry-run robot) and ``abm calibrate``
(hand-eye calibration of a fixed camera with a gripper-mounted ChArUco board)."""

from __future__ import annotations

import argparse

from abm.cli import CommandError
from abm.grounding.grounders import override_spec
from abm.policy import KeyframePolicy
from abm.robot.calibration import BoardSpec, calibrate_from_recording, load_calibration, save_calibration
from abm.robot.devices import record_observations
from abm.robot.limits import LimitError
from abm.robot.run import NoTargetError, RobotConfig, run_robot


def parse_board(text: str):
    """``"5x7:0.04:0.03:DICT_4X4_50"`` -> :class:`abm.robot.calibration.BoardSpec`."""
    try:
        squares, square, marker, dictionary = text.split(":")
        sx, sy = (int(v) for v in squares.lower().split("x"))
        return BoardSpec((sx, sy), float(square), float(marker), dictionary)
    except ValueError:
        raise ValueError(f"--board {text!r}: expected XxY:SQUARE_M:MARKER_M:DICTIONARY, e.g. "
                         "5x7:0.04:0.03:DICT_4X4_50") from None


def calibrate(args: argparse.Namespace) -> int:
    spec = parse_board(args.board)
    intrinsics, extrinsics, stats = calibrate_from_recording(args.recording, args.camera, spec)
    cameras = load_calibration(args.out) if args.out.is_file() else {}
    cameras[args.camera] = {"intrinsics": intrinsics, "extrinsics": extrinsics}
    save_calibration(args.out, cameras)
    print(f"abm calibrate: {args.camera} from {stats['views']} views (reprojection {stats['reprojection_px']:.2f} px)"
          f" -> {args.out}")
    return 0


def run_record(args: argparse.Namespace) -> int:
    from abm.sim.env import TaskEnv, run_expert  # mujoco (optional `sim` extra): `abm run`/`calibrate` need none

    with TaskEnv(args.task, args.split, args.seed, resolution=args.resolution) as env:
        episode = run_expert(env)
    record_observations([obs for obs, _ in episode.steps], args.out, episode.object_names, episode.instruction)
    print(f"abm record: {len(episode.steps)} frames of {episode.instruction!r} -> {args.out} (replay it with "
          f"cameras: {{kind: replay, path: {args.out}}}, e.g. examples/robot_replay.yaml)")
    return 0


def run(args: argparse.Namespace) -> int:
    if not args.robot.is_file():
        raise CommandError(f"--robot {args.robot} is not a file")
    if args.steps < 1:
        raise CommandError("--steps must be at least 1")
    try:
        grounder = override_spec(args.grounder, args.clip_model)
    except ValueError as err:
        raise CommandError(str(err)) from err
    config = RobotConfig.load(args.robot)
    camera, arm = config.build(dry_run=args.dry_run)
    instruction = args.instruction or getattr(camera, "instruction", "")
    if not instruction:
        raise CommandError("give --instruction (the camera source has none)")
    policy = KeyframePolicy.from_checkpoint(args.run, device=args.device, grounder=grounder)
    try:
        records = run_robot(policy, camera, arm, instruction, config.limits, args.steps, args.log,
                            allow_no_target=args.allow_no_target)
    except (LimitError, NoTargetError) as err:
        raise CommandError(f"refused before moving: {err} (log: {args.log})") from None
    finally:
        if hasattr(camera, "close"):
            camera.close()
    done = " (task succeeded)" if records and records[-1].get("success") else ""
    print(f"abm run: {len(records)} keyframes{done}; log: {args.log / 'steps.jsonl'}")
    return 0
