"""``abm run`` (a trained policy on a recorded, simulated or dry-run robot) and ``abm calibrate``
(hand-eye calibration of a fixed camera with a gripper-mounted ChArUco board)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from abm.configuration import MAX_KEYFRAMES, clip_model_help, int_range, seed_int
from abm.grounding.config import GROUNDERS

BOARD_FORMAT = "XxY:SQUARE_M:MARKER_M:DICTIONARY, e.g. 5x7:0.04:0.03:DICT_4X4_50"


def parse_board_text(text: str) -> tuple[tuple[int, int], float, float, str]:
    """``((x, y), square_m, marker_m, dictionary)`` of a ``--board`` value, checked: at least 2 x 2 squares (at
    most 1000 each), a square side in ``(0, 1]`` m, a marker side above 0 and smaller than the square, and an ArUco
    dictionary name (``DICT_...``).

    Raises:
        argparse.ArgumentTypeError: what is wrong, and the expected form.
    """
    parts = str(text).split(":")
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"expected {BOARD_FORMAT}, got {text!r}")
    squares, square, marker, dictionary = (part.strip() for part in parts)
    try:
        sx, sy = (int(v) for v in squares.lower().split("x"))
        square_m, marker_m = float(square), float(marker)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {BOARD_FORMAT}, got {text!r}") from None
    if not (2 <= sx <= 1000 and 2 <= sy <= 1000):
        raise argparse.ArgumentTypeError(f"{text!r}: the board needs 2 to 1000 squares each way, got {sx}x{sy}")
    if not (math.isfinite(square_m) and 0 < square_m <= 1):
        raise argparse.ArgumentTypeError(f"{text!r}: the square side is in metres and must be > 0 and <= 1, got "
                                         f"{square}")
    if not (math.isfinite(marker_m) and 0 < marker_m < square_m):
        raise argparse.ArgumentTypeError(f"{text!r}: the marker side is in metres and must be > 0 and smaller than "
                                         f"the square ({square}), got {marker}")
    if not dictionary.startswith("DICT_"):
        raise argparse.ArgumentTypeError(f"{text!r}: expected an ArUco dictionary name such as DICT_4X4_50, got "
                                         f"{dictionary!r}")
    return (sx, sy), square_m, marker_m, dictionary


def board_spec(text: str) -> str:
    """The argparse ``type`` of ``--board``: the text, once :func:`parse_board_text` accepts it."""
    parse_board_text(text)
    return text


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
                   help="act even when the instruction's object is not one the grounder found with confidence "
                   "(absent from the scene, ambiguous, not found, unsure; by default such a step is refused before "
                   "anything moves, exit code 2)")
    p.add_argument("--steps", type=int_range(1, 10_000), default=MAX_KEYFRAMES, help="keyframes to run")
    p.add_argument("--grounder", choices=GROUNDERS.names(), help="override the checkpoint's grounder")
    p.add_argument("--clip-model", help=clip_model_help(f"of --grounder {' or '.join(GROUNDERS.names(clip=True))} "
                                                        "(default: the checkpoint's)", default=None))
    p.add_argument("--device", default="cpu", help="torch device of the policy")
    p.add_argument("--log", type=Path, default=Path("runs/robot_log"), help="log folder (default: runs/robot_log)")
    p.set_defaults(func="abm.cli.commands.robot:run")

    r = subparsers.add_parser(
        "record", help="record a scripted-expert episode in the simulator as frames abm run can replay",
        description="Run the scripted expert on one seeded ABM-Bench scene and write its camera frames, gripper "
        "states, object names and instruction to a recording folder: `cameras: {kind: replay, path: OUT}` in a "
        "robot YAML plays it back (examples/robot_replay.yaml).")
    r.add_argument("--task", default="pick_block", help="ABM-Bench task (abm tasks lists them)")
    r.add_argument("--split", default="seen", choices=["seen", "unseen"], help="object split of the scene")
    r.add_argument("--seed", type=seed_int, default=0, help="scene seed")
    r.add_argument("--resolution", type=int_range(16, 1024), default=64, help="camera image side in pixels")
    r.add_argument("--out", type=Path, required=True, help="recording folder to write (new or empty)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace the recording --out already holds (its meta.json and step_*.npz; other files "
                   "are left alone)")
    r.set_defaults(func="abm.cli.commands.robot:run_record")

    c = subparsers.add_parser(
        "calibrate", help="hand-eye calibration of a fixed camera from a recording of a gripper-held ChArUco board",
        description="Reads a recording (abm.robot.record_observations) in which the arm showed a ChArUco board "
        "fixed to the gripper in several poses, finds the board in each image, solves the hand-eye problem and "
        "writes the camera's intrinsics and camera-to-base transform into the calibration file (other cameras "
        "in it are kept).")
    c.add_argument("--recording", type=Path, required=True, help="recording folder")
    c.add_argument("--camera", required=True, help="camera name (or serial) in the recording")
    c.add_argument("--out", type=Path, required=True, help="calibration YAML to write or update")
    c.add_argument("--board", type=board_spec, default="5x7:0.04:0.03:DICT_4X4_50",
                   help="squares XxY : square m : marker m : ArUco dictionary (default: 5x7:0.04:0.03:DICT_4X4_50)")
    c.set_defaults(func="abm.cli.commands.robot:calibrate")
