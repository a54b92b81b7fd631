"""``abm run``: a trained policy on a (recorded, simulated or dry-run) robot."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run", help="run a trained policy on a robot (recorded camera, MuJoCo arm or dry run), logged per step",
        description="observe -> ground -> predict -> check limits -> move, for --steps keyframes. The robot "
        "YAML names the camera source, the arm and the motion limits (see abm.robot.run). A keyframe "
        "outside the limits stops the run before anything moves (exit code 2).")
    p.add_argument("--robot", type=Path, required=True, help="robot YAML (cameras, arm, limits)")
    p.add_argument("--run", type=Path, required=True, help="training run folder or checkpoint")
    p.add_argument("--instruction", help="the instruction (default: the recording's or the scene's)")
    p.add_argument("--dry-run", action="store_true", help="never move the arm: log the commands only")
    p.add_argument("--steps", type=int, default=10, help="keyframes to run (default: 10)")
    p.add_argument("--grounder", choices=["oracle", "clip", "tracking"], help="override the checkpoint's grounder")
    p.add_argument("--device", default="cpu", help="torch device of the policy")
    p.add_argument("--log", type=Path, default=Path("runs/robot_log"), help="log folder (default: runs/robot_log)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError
    from abm.policy import KeyframePolicy
    from abm.robot.limits import LimitError
    from abm.robot.run import RobotConfig, run_robot

    if not args.robot.is_file():
        raise CommandError(f"--robot {args.robot} is not a file")
    if args.steps < 1:
        raise CommandError("--steps must be at least 1")
    config = RobotConfig.load(args.robot)
    camera, arm = config.build(dry_run=args.dry_run)
    instruction = args.instruction or getattr(camera, "instruction", "")
    if not instruction:
        raise CommandError("give --instruction (the camera source has none)")
    policy = KeyframePolicy.from_checkpoint(args.run, device=args.device,
                                            grounder={"kind": args.grounder} if args.grounder else None)
    try:
        records = run_robot(policy, camera, arm, instruction, config.limits, args.steps, args.log)
    except LimitError as err:
        raise CommandError(f"refused before moving: {err} (log: {args.log})") from None
    finally:
        if hasattr(camera, "close"):
            camera.close()
    done = " (task succeeded)" if records and records[-1].get("success") else ""
    print(f"abm run: {len(records)} keyframes{done}; log: {args.log / 'steps.jsonl'}")
    return 0
