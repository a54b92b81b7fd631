"""``abm run`` and ``abm ground`` resolve instructions in plain words onto the scene's objects (issue 40 item 4)
before the name check, so "grab the yellow one" reaches the policy as "put the yellow block on the target"."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from abm.language.resolve import UnresolvedInstructionError
from abm.robot import DryRunArm, MotionLimits, NoTargetError, run_robot
from abm.robot.run import resolve_for_policy
from abm.types import CameraFrame, KeyframeAction

NAMES = {1: "target", 2: "red block", 3: "yellow block"}
OPEN = MotionLimits(workspace_lower=(-1.0, -1.0, -1.0), workspace_upper=(1.0, 1.0, 1.0), max_step_m=5.0,
                    max_tilt_deg=180.0)


class Camera:
    """Four-pixel images of a scene that names its objects."""

    object_names = NAMES

    def read(self) -> dict[str, CameraFrame]:
        return {"front": CameraFrame(np.zeros((2, 2, 3), np.uint8), np.ones((2, 2), np.float32), np.eye(3),
                                     np.eye(4))}


@dataclass
class Seen:
    action: KeyframeAction
    view_images: np.ndarray = field(default_factory=lambda: np.zeros((5, 4, 2, 2), np.float32))
    view_mask: None = None
    sample: dict[str, Any] = field(default_factory=dict)


class Policy:
    """Records the instruction it is given; always asks for the same keyframe."""

    grounder = None
    last_timings: dict[str, float] = {}

    def __init__(self) -> None:
        self.instructions: list[str] = []

    def reset(self) -> None:
        pass

    def explain(self, obs: Any, instruction: str, names: Any) -> Seen:
        self.instructions.append(instruction)
        return Seen(KeyframeAction([0.5, 0.0, 0.2], [1.0, 0.0, 0.0, 0.0], True))


def test_run_gives_the_policy_the_resolved_instruction(tmp_path) -> None:
    policy, arm = Policy(), DryRunArm()
    run_robot(policy, Camera(), arm, "grab the yellow one", OPEN, 1, tmp_path / "a")
    assert policy.instructions == ["put the yellow block on the target"] and len(arm.commands) == 1
    first = json.loads((tmp_path / "a/steps.jsonl").read_text().splitlines()[0])
    assert first["instruction"] == "grab the yellow one"
    assert first["resolved"]["target"] == "yellow block" and first["resolved"]["task"] == "pick_block"
    # an instruction the templates read as a scene object reaches the policy unchanged
    policy = Policy()
    run_robot(policy, Camera(), DryRunArm(), "place the red block onto the target area", OPEN, 1, tmp_path / "b")
    assert policy.instructions == ["place the red block onto the target area"]


def test_run_refuses_before_moving(tmp_path) -> None:
    policy, arm = Policy(), DryRunArm()
    with pytest.raises(UnresolvedInstructionError, match="Known skills"):
        run_robot(policy, Camera(), arm, "grab the purple one", OPEN, 1, tmp_path / "a")
    # a named object the scene lacks: the name check says so, as before
    with pytest.raises(NoTargetError, match="'ketchup' is not in the scene"):
        run_robot(policy, Camera(), arm, "put the ketchup on the target", OPEN, 1, tmp_path / "b")
    assert policy.instructions == [] and arm.commands == []


def test_resolve_for_policy_without_names_keeps_the_text() -> None:
    assert resolve_for_policy("grab the yellow one", None) == ("grab the yellow one", None)
    text, resolution = resolve_for_policy("put the yellow cube on the pad", NAMES)
    assert text == "put the yellow block on the target" and resolution is not None and resolution.method == "synonyms"


def test_abm_ground_grounds_the_resolved_object(tmp_path, capsys) -> None:
    from abm.cli import main as cli_main
    from abm.render.synthetic import synthetic_scene

    _, names = synthetic_scene(seed=0)
    colour = sorted(names.values())[0].split()[0]
    out = tmp_path / "g"
    assert cli_main(["ground", "--instruction", f"put the {colour} cube in the plate", "--out", str(out),
                     "--resolution", "32", "--strict"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["target"] == f"{colour} block" and summary["target_in_scene"]
    assert summary["resolved"]["phrase"] == f"{colour} block" and summary["decision"]["found"]
    assert cli_main(["ground", "--instruction", "grab the purple elephant", "--out", str(tmp_path / "h"),
                     "--resolution", "32"]) == 2
    assert "Known skills" in capsys.readouterr().err
