"""Offline keyframe accuracy: per-kind scoring against the expert with symmetry-aware rotation error."""

from __future__ import annotations

import numpy as np
import pytest

from abm.evaluation.keyframe_accuracy import (
    keyframe_errors,
    markdown,
    score_keyframe,
    skill_text_probe,
    summarise,
    task_skills,
)
from abm.evaluation.results import eval_seed
from abm.geometry import matrix_to_quat
from abm.sim.env import make_env, run_expert
from abm.types import KeyframeAction


def _down(yaw_deg: float) -> np.ndarray:
    yaw = np.radians(yaw_deg)
    y = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    return matrix_to_quat(np.stack([np.cross(y, z), y, z], axis=1))


def test_score_keyframe_uses_the_label_symmetry() -> None:
    label = KeyframeAction([0.5, 0.0, 0.1], _down(-45.0), False, kind="grasp", symmetry=4)
    pred = KeyframeAction([0.5, 0.03, 0.14], _down(45.0), True)  # 90° turn: the same grasp of a cube
    pos, rot, grip = score_keyframe(pred, label)
    assert abs(pos - 5.0) < 1e-6 and rot < 1e-6 and not grip
    two_fold = KeyframeAction(label.position, label.quaternion, False, kind="grasp", symmetry=2)
    assert abs(score_keyframe(pred, two_fold)[1] - 90.0) < 1e-6


def test_keyframe_errors_score_every_expert_keyframe() -> None:
    fixed = KeyframeAction([0.45, 0.05, 0.3], _down(-45.0), True)
    errors = keyframe_errors({"fixed": lambda obs, instr, names: fixed}, "pick_block", "seen", episodes=1,
                             resolution=16)
    with make_env("pick_block", "seen", eval_seed(0, 0), 16) as env:
        labels = [a for _, a in run_expert(env).steps]
    assert [e.kind for e in errors] == [a.kind for a in labels]
    for e, label in zip(errors, labels, strict=True):
        assert abs(e.position_cm - 100 * np.linalg.norm(fixed.position - label.position)) < 1e-6
        assert e.gripper_agrees == label.gripper_open
    rows = summarise(errors)
    assert {r["kind"] for r in rows} == {a.kind for a in labels}
    table = markdown(rows, kinds=["grasp"])
    assert table.count("\n") == 2 and "| fixed | pick_block | seen | grasp | 1 |" in table


def test_skill_text_probe_reports_how_far_each_skill_text_moves_the_prediction() -> None:
    skills = task_skills(["place_wine", "take_off_pan"])
    assert skills == {"put X in the wine rack": "place_wine", "take X off the frypan": "take_off_pan"}

    def reads_its_text(obs, instruction: str, names) -> KeyframeAction:  # 10 cm along x for "frypan"
        return KeyframeAction([0.5 + 0.1 * ("frypan" in instruction), 0.0, 0.3], _down(0.0), False)

    rows = skill_text_probe(reads_its_text, "place_wine", "seen", 1, "move", list(skills), resolution=16)
    with make_env("place_wine", "seen", eval_seed(0, 0), 16) as env:
        move = next(a for _, a in run_expert(env).steps if a.kind == "move")
    own, other = rows
    assert (own["skill"], own["own"], own["n"], other["own"]) == ("put X in the wine rack", True, 1, False)
    assert own["moved_cm_median"] == 0.0 and abs(other["moved_cm_median"] - 10.0) < 1e-6
    assert abs(own["position_cm_median"] - 100 * np.linalg.norm(np.array([0.5, 0.0, 0.3]) - move.position)) < 1e-6
    with pytest.raises(ValueError, match="no successful expert rollout .* 'pour' keyframe"):
        skill_text_probe(reads_its_text, "place_wine", "seen", 1, "pour", list(skills), resolution=16)
