"""``abm run`` (a trained policy on a recorded, simulated or dry-run robot) and ``abm calibrate``
(hand-eye calibration of a fixed camera with a gripper-mounted ChArUco board)."""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import int_range, seed_int


def register(subparsers: argparse._SubParsersAction) -> None:
    from abm.configuration import MAX_KEYFRAMES, clip_model_help

    p = subparsers.add_parser(
        "run", help="run a trained policy on a robot (recorded camera, MuJoCo arm or dry run), logged per step",
        description="observe -> ground -> predict -> check limits -> move, for --steps keyframes. The robot "
        "YAML names the camera source, the arm and the motion limits (see abm.robot.run). A keyframe "
        "outside the limits stops the run before anything moves (exit code 2).")
    p.add_argument("--robot", type=Path, required=True, help="robot YAML (cameras, arm, limits)")
    p.add_argument("--run", type=Path, required=True, help="training run folder or checkpoint")
    p.add_argument("--instruction", help="the instruction (default: the recording's or the scene's)")
    p.add_argument("--dry-run", action="store_true", help="never move the arm: log the commands only")
    p.add_argument("--allow-no-target", action="store_true",
                   help="move even when grounding finds no point of the instruction's object (by default such a "
                   "step is refused before anything moves, exit code 2)")
    p.add_argument("--steps", type=int_range(1, 10_000), default=MAX_KEYFRAMES, help="keyframes to run")
    p.add_argument("--grounder", choices=["oracle", "clip", "tracking"], help="override the checkpoint's grounder")
    p.add_argument("--clip-model", help=clip_model_help("of --grounder clip or tracking (default: the "
                                                        "checkpoint's)", default=None))
    p.add_argument("--device", default="cpu", help="torch device of the policy")
    p.add_argument("--log", type=Path, default=Path("runs/robot_log"), help="log folder (default: runs/robot_log)")
    p.set_defaults(func=run)

    r = subparsers.add_parser(
        "record", help="record a scripted-expert episode in the simulator as frames abm run can replay",
        description="Run the scripted expert on one seeded ABM-Bench scene and write its camera frames, gripper "
        "states, object names and instruction to a recording folder: `cameras: {kind: replay, path: OUT}` in a "
        "robot YAML plays it back (examples/robot_replay.yaml).")
    r.add_argument("--task", default="pick_block", help="ABM-Bench task (abm tasks lists them)")
    r.add_argument("--split", default="seen", choices=["seen", "unseen"], help="object split of the scene")
    r.add_argument("--seed", type=seed_int, default=0, help="scene seed")
    r.add_argument("--resolution", type=int_range(16, 1024), default=64, help="camera image side in pixels")
    r.add_argument("--out", type=Path, required=True, help="recording folder to write")
    r.set_defaults(func=run_record)

    c = subparsers.add_parser(
        "calibrate", help="hand-eye calibration of a fixed camera from a recording of a gripper-held ChArUco board",
        description="Reads a recording (abm.robot.record_observations) in which the arm showed a ChArUco board "
        "fixed to the gripper in several poses, finds the board in each image, solves the hand-eye problem and "
        "writes the camera's intrinsics and camera-to-base transform into the calibration file (other cameras "
        "in it are kept).")
    c.add_argument("--recording", type=Path, required=True, help="recording folder")
    c.add_argument("--camera", required=True, help="camera name (or serial) in the recording")
    c.add_argument("--out", type=Path, required=True, help="calibration YAML to write or update")
    c.add_argument("--board", default="5x7:0.04:0.03:DICT_4X4_50",
                   help="squares XxY : square m : marker m : ArUco dictionary (default: 5x7:0.04:0.03:DICT_4X4_50)")
    c.set_defaults(func=calibrate)


def parse_board(text: str):
    """``"5x7:0.04:0.03:DICT_4X4_50"`` -> :class:`abm.robot.calibration.BoardSpec`."""
    from abm.robot.calibration import BoardSpec

    try:
        squares, square, marker, dictionary = text.split(":")
        sx, sy = (int(v) for v in squares.lower().split("x"))
        return BoardSpec((sx, sy), float(square), float(marker), dictionary)
    except ValueError:
        raise ValueError(f"--board {text!r}: expected XxY:SQUARE_M:MARKER_M:DICTIONARY, e.g. "
                         "5x7:0.04:0.03:DICT_4X4_50") from None


def calibrate(args: argparse.Namespace) -> int:
    from abm.robot.calibration import calibrate_from_recording, load_calibration, save_calibration

    spec = parse_board(args.board)
    intrinsics, extrinsics, stats = calibrate_from_recording(args.recording, args.camera, spec)
    cameras = load_calibration(args.out) if args.out.is_file() else {}
    cameras[args.camera] = {"intrinsics": intrinsics, "extrinsics": extrinsics}
    save_calibration(args.out, cameras)
    print(f"abm calibrate: {args.camera} from {stats['views']} views (reprojection {stats['reprojection_px']:.2f} px)"
          f" -> {args.out}")
    return 0


def run_record(args: argparse.Namespace) -> int:
    from abm.robot.devices import record_observations
    from abm.sim.env import TaskEnv, run_expert

    with TaskEnv(args.task, args.split, args.seed, resolution=args.resolution) as env:
        episode = run_expert(env)
    record_observations([obs for obs, _ in episode.steps], args.out, episode.object_names, episode.instruction)
    print(f"abm record: {len(episode.steps)} frames of {episode.instruction!r} -> {args.out} (replay it with "
          f"cameras: {{kind: replay, path: {args.out}}}, e.g. examples/robot_replay.yaml)")
    return 0


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.grounding.grounders import override_spec
    from abm.policy import KeyframePolicy
    from abm.robot.limits import LimitError
    from abm.robot.run import NoTargetError, RobotConfig, run_robot

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
