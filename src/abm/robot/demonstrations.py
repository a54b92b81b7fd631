"""Demonstrations recorded on a real robot, stored as episodes in the simulator's format
(:mod:`abm.data.episode_store`), so ``abm train --data DIR`` trains on them like on generated data.

A demonstration is a list of **snapshots**, one per keyframe, the first at the start pose: the operator moves
the arm (freedrive) to each keyframe, sets the gripper as it should be there, and captures camera frames and
the arm's TCP pose. Step ``k`` of the episode is ``(snapshot k, keyframe = snapshot k+1's pose and
gripper)``, as in the simulator's demonstrations (move, then open or close the gripper). Orientation labels
are stored in the canonical member of the gripper's symmetry class, as the simulator's are.

What a real robot lacks: segmentation and object names. The oracle grounder (``abm train --grounder
oracle``, the default) cannot use such episodes; train with ``--grounder clip`` or a method without a mask
(``rvt``). The instruction must match one of abm's skill templates (checked when recording), because the
policy conditions on the skill text.

Command line (interactive; Enter captures a keyframe, ``o`` / ``c`` open / close the gripper, ``u`` drops the
last keyframe, ``q`` saves)::

    python -m abm.robot.demonstrations --robot robot.yaml --instruction "put the mug on the target" --out data/real
"""

from __future__ import annotations

import argparse
import datetime
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from abm.configuration import count
from abm.data.episode_store import save_episode
from abm.errors import ConfigError
from abm.geometry.rotations import canonical_gripper_quat, matrix_to_quat
from abm.language.roles import split_instruction
from abm.robot.run import RobotConfig
from abm.robot.ur import URArm
from abm.types import Episode, KeyframeAction, Observation

HELP = "Enter: capture keyframe | o: open gripper | c: close gripper | u: drop last keyframe | q: save and quit"


def capture(camera: Any, arm: Any, step: int = 0) -> Observation:
    """One snapshot: every camera's frame and the arm's TCP pose ``(4, 4)`` (base frame, m) and opening."""
    frames = camera.read()
    pose, opening = arm.state()
    return Observation(frames, opening, pose, step)


def check_instruction(instruction: str, object_names: Mapping[int, str] | None = None) -> tuple[str, str]:
    """``(target X, skill text)`` of ``instruction``; ``ValueError`` that says how to fix an instruction no skill
    template matches."""
    try:
        return split_instruction(instruction, object_names)
    except ValueError as err:
        raise ConfigError(f"instruction {instruction!r} matches no skill template ({err}); use a phrasing that "
                          "`abm tasks` lists, or add a template (docs/grounding.md)") from None


def episode_from_snapshots(snapshots: Sequence[Observation], instruction: str, *, task: str = "real",
                           split: str = "seen", object_names: Mapping[int, str] | None = None,
                           kinds: Sequence[str] | None = None, symmetry: int = 2,
                           metadata: Mapping[str, Any] | None = None) -> Episode:
    """An :class:`Episode` of ``len(snapshots) - 1`` keyframes (see the module docstring).

    Args:
        snapshots: observations at the start pose and at each keyframe (at least 2).
        kinds: keyframe kinds (``"approach"``, ``"grasp"``, ...), one per keyframe after the start; default empty.
        symmetry: turns about the gripper axis that give the same keyframe (2: a parallel gripper).
    """
    if len(snapshots) < 2:
        raise ValueError(f"a demonstration needs the start and at least one keyframe, got {len(snapshots)} snapshots")
    if kinds is not None and len(kinds) != len(snapshots) - 1:
        raise ValueError(f"{len(kinds)} keyframe kinds for {len(snapshots) - 1} keyframes")
    steps = []
    for k, (obs, nxt) in enumerate(zip(snapshots[:-1], snapshots[1:], strict=True)):
        quat = canonical_gripper_quat(matrix_to_quat(nxt.gripper_pose[:3, :3]), symmetry)
        action = KeyframeAction(nxt.gripper_pose[:3, 3], quat, nxt.gripper_open > 0.5,
                                kind=kinds[k] if kinds else "", symmetry=symmetry)
        steps.append((Observation(obs.cameras, obs.gripper_open, obs.gripper_pose, k), action))
    meta = {"source": "real-robot", "recorded": datetime.datetime.now().isoformat(timespec="seconds"),
            **dict(metadata or {})}
    return Episode(task=task, variation=0, split=split, instruction=instruction,
                   object_names=dict(object_names or {}), target_names=[], steps=steps, success=True,
                   metadata=meta)


def next_episode_path(out_dir: str | Path, task: str, split: str) -> Path:
    """``OUT/<task>/<split>/episode_NNNNNN.h5`` (the layout of ``abm data generate``), first free number."""
    folder = Path(out_dir) / task / split
    taken = {p.stem for p in folder.glob("episode_*.h5")} if folder.is_dir() else set()
    n = 0
    while f"episode_{n:06d}" in taken:
        n += 1
    return folder / f"episode_{n:06d}.h5"


def _set_gripper(arm: Any, open_: bool) -> bool:
    if hasattr(arm, "gripper"):
        arm.gripper.set_open(open_)
    elif hasattr(arm, "gripper_open"):  # DryRunArm
        arm.gripper_open = float(open_)
    else:
        return False
    return True


def _prompt() -> Iterator[str]:
    while True:
        try:
            yield input(f"[{HELP}] > ")
        except EOFError:  # end of input (Ctrl-D): save what was captured
            yield "q"
            return


def record_demonstration(camera: Any, arm: Any, instruction: str, out_dir: str | Path, *, task: str = "real",
                         split: str = "seen", symmetry: int = 2, commands: Iterator[str] | None = None,
                         echo: Callable[[str], None] = print) -> Path:
    """Record one demonstration interactively and save it as an episode file; returns its path.

    Args:
        camera / arm: the camera and arm interfaces (:mod:`abm.robot.devices`); the arm is only read (and its
            gripper switched on ``o`` / ``c``), never moved.
        commands: the operator's inputs (default: prompts on the terminal); see :data:`HELP`.
    """
    object_names = dict(getattr(camera, "object_names", {}) or {})
    check_instruction(instruction, object_names)
    snapshots: list[Observation] = []
    for command in commands if commands is not None else _prompt():
        command = command.strip().lower()
        if command == "":
            snapshots.append(capture(camera, arm, len(snapshots)))
            pose = snapshots[-1].gripper_pose[:3, 3]
            echo(f"keyframe {len(snapshots) - 1} at {[round(float(v), 3) for v in pose]} m, gripper "
                 f"{'open' if snapshots[-1].gripper_open > 0.5 else 'closed'}")
        elif command in ("o", "c"):
            if not _set_gripper(arm, command == "o"):
                echo("this arm's gripper cannot be switched from here")
        elif command == "u":
            echo(f"dropped keyframe {len(snapshots) - 1}" if snapshots else "nothing to drop")
            del snapshots[-1:]
        elif command == "q":
            break
        else:
            echo(f"unknown command {command!r}; {HELP}")
    episode = episode_from_snapshots(snapshots, instruction, task=task, split=split, object_names=object_names,
                                     symmetry=symmetry, metadata={"cameras": sorted(snapshots[0].cameras)}
                                     if snapshots else None)
    path = next_episode_path(out_dir, task, split)
    save_episode(episode, path)
    echo(f"saved {len(episode)} keyframes to {path}")
    return path


def recording_devices(robot_yaml: str | Path) -> tuple[Any, Any]:
    """Camera and arm of a robot YAML for recording: a UR arm is opened read-only (no control script, so the
    pendant's freedrive works) with a live gripper; other arms as ``abm run`` builds them."""
    config = RobotConfig.load(robot_yaml)
    if config.arm.get("kind") != "ur":
        return config.build()

    return config.build_camera(), URArm.from_config(config.arm, read_only=True, gripper_dry_run=False)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m abm.robot.demonstrations``: record one demonstration (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m abm.robot.demonstrations", description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", type=Path, required=True, help="robot YAML (cameras, arm)")
    p.add_argument("--instruction", required=True, help="what the demonstration does (matches a skill template)")
    p.add_argument("--out", type=Path, required=True, help="episode folder (OUT/<task>/<split>/episode_N.h5)")
    p.add_argument("--task", default="real", help="task name stored with the episode (default: real)")
    p.add_argument("--split", default="seen", choices=["seen", "unseen", "compositional"])
    p.add_argument("--symmetry", type=count, default=2, help="gripper symmetry of the keyframes (default: 2)")
    args = p.parse_args(argv)
    camera, arm = recording_devices(args.robot)
    try:
        record_demonstration(camera, arm, args.instruction, args.out, task=args.task, split=args.split,
                             symmetry=args.symmetry)
    finally:
        for device in {id(camera): camera, id(arm): arm}.values():
            if hasattr(device, "close"):
                device.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
