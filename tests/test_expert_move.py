"""The expert-move evaluation (``abm eval --expert-keyframes move``): which predicted step is the move, the step
record that says it was replaced, the settings that key such outcomes apart, and a real rollout of a zoo model
whose replaced step executes the expert's move keyframe."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from abm.errors import ConfigError
from abm.evaluation.expert_move import ExpertMove
from abm.evaluation.settings import EvalSettings
from abm.evaluation.step_records import StepRecord, step_record
from abm.types import KeyframeAction

ZOO = Path(__file__).resolve().parents[1] / "models"
TOP = np.array([1.0, 0.0, 0.0, 0.0])  # gripper pointing down


def _key(x: float, z: float, kind: str = "", gripper_open: bool = False) -> KeyframeAction:
    return KeyframeAction(np.array([x, 0.0, z]), TOP, gripper_open, kind=kind)


# the expert: approach, grasp, lift at x=0.3; move, place, retreat at x=0.6
EXPERT = (_key(0.3, 0.15, "approach", True), _key(0.3, 0.02, "grasp"), _key(0.3, 0.17, "lift"),
          _key(0.6, 0.17, "move"), _key(0.6, 0.04, "place", True), _key(0.6, 0.15, "retreat", True))
LIFT = _key(0.3, 0.16)  # nearest expert keyframe: the lift
TOWARDS = _key(0.55, 0.17)  # nearest: the move


def _run(rule: ExpertMove, steps: list[tuple[KeyframeAction, bool]]) -> list[bool]:
    """Whether each (prediction, held before the step) was replaced by the expert's move."""
    return [rule.choose(action, held) is not action for action, held in steps]


def test_the_move_is_the_step_after_the_lift_of_a_holding_once() -> None:
    rule = ExpertMove(EXPERT)
    # approach, grasp (not held before either), lift (held since the grasp), then the move, then a loop
    replaced = _run(rule, [(LIFT, False), (LIFT, False), (LIFT, True), (LIFT, True), (LIFT, True), (TOWARDS, True)])
    assert replaced == [False, False, False, True, False, False]
    assert rule.steps == [3]
    executed = ExpertMove(EXPERT)
    for action, held in [(LIFT, False), (LIFT, True)]:
        executed.choose(action, held)
    assert executed.choose(LIFT, True) is EXPERT[3]  # the expert's move keyframe itself


def test_a_policy_heading_for_the_destination_right_after_the_grasp_gets_the_move_then() -> None:
    assert _run(ExpertMove(EXPERT), [(LIFT, False), (TOWARDS, True)]) == [False, True]
    beyond = _key(0.6, 0.05)  # nearest: the place, after the move
    assert _run(ExpertMove(EXPERT), [(LIFT, False), (beyond, True)]) == [False, True]


def test_a_new_holding_after_a_drop_is_moved_again_and_no_expert_move_replaces_nothing() -> None:
    rule = ExpertMove(EXPERT)
    held = [False, True, True, False, True, True]  # grasp, lift, move (dropped), re-grasp, lift, move
    assert _run(rule, [(LIFT, h) for h in held]) == [False, False, True, False, False, True]
    assert rule.holdings == 2
    assert _run(ExpertMove(()), [(LIFT, h) for h in held]) == [False] * 6
    assert _run(ExpertMove(EXPERT[:3]), [(LIFT, h) for h in held]) == [False] * 6


def test_a_replaced_step_records_the_expert_kind_and_the_policys_own_keyframe() -> None:
    record = step_record(EXPERT[3], "reached", True, 0.001, EXPERT, predicted=LIFT)
    assert (record.substituted, record.expert_kind, record.expert_cm) == ("move", "move", 0.0)
    data = record.to_json()
    assert data["substituted"] == "move" and data["policy_pos"] == [0.3, 0.0, 0.16] and data["pos"] == [0.6, 0.0, 0.17]
    assert StepRecord.from_json(data) == StepRecord.from_json(StepRecord.from_json(data).to_json())
    assert StepRecord.from_json(data).policy_pose == (0.3, 0.0, 0.16, 1.0, 0.0, 0.0, 0.0)
    plain = step_record(LIFT, "reached", True, 0.001, EXPERT).to_json()
    assert not {"substituted", "policy_pos", "policy_quat"} & set(plain)  # default records unchanged


def test_the_setting_keys_outcomes_apart_and_leaves_the_default_signature_as_it_was() -> None:
    assert EvalSettings().signature() == (
        '{"grounder": null, "max_steps": 8, "resolution": 128, "splits_path": null}')
    assert '"expert_keyframes": "move"' in EvalSettings(expert_keyframes="move").signature()
    with pytest.raises(ConfigError, match="expert_keyframes: expected one of move, got 'place'"):
        EvalSettings(expert_keyframes="place")


def test_abm_eval_takes_the_flag(capsys) -> None:
    import argparse

    from abm.cli.evaluate import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["eval", "--run", "x.pt", "--expert-keyframes", "move"])
    assert args.expert_keyframes == "move"
    with pytest.raises(SystemExit):
        parser.parse_args(["eval", "--run", "x.pt", "--expert-keyframes", "grasp"])
    assert "invalid choice: 'grasp'" in capsys.readouterr().err


def test_a_zoo_models_rollout_executes_the_experts_move_keyframe_where_it_looped() -> None:
    from sim_helpers import require_simulator

    require_simulator()
    model = ZOO / "abm_oracle_v2.pt"
    if not model.is_file():
        pytest.skip("the committed model zoo is not in this checkout")
    from abm.evaluation.results import eval_seed
    from abm.evaluation.runner import EvalJob, run_job
    from abm.evaluation.step_records import expert_keyframes
    from abm.sim.env import make_env

    seed = eval_seed(0, 1)  # pick_block, seen, episode 1: the policy lifts a second time where it should move
    job = EvalJob(str(model), "abm", "pick_block", "seen", 0, 1, seed, checkpoint=str(model))
    moved = run_job(job, EvalSettings(max_steps=4, expert_keyframes="move"))
    plain = run_job(job, EvalSettings(max_steps=3))
    assert not moved.error and not plain.error
    replaced = [i for i, r in enumerate(moved.step_records) if r.get("substituted")]
    assert replaced == [3]
    with make_env("pick_block", "seen", seed) as env:
        move = next(k for k in expert_keyframes(env) if k.kind == "move")
    step = moved.step_records[3]
    assert np.allclose(step["pos"], move.position, atol=1e-4)
    assert np.allclose(step["quat"], move.quaternion, atol=1e-4)
    assert (step["expert"], step["expert_cm"], step["open"]) == ("move", 0.0, False)
    assert step["policy_pos"][0] == pytest.approx(plain.step_records[2]["pos"][0], abs=0.02)  # a lift in place
    assert np.linalg.norm(np.subtract(step["policy_pos"], move.position)) > 0.2
    # until the move, the rollout is the plain one's, step for step
    assert [r["pos"] for r in moved.step_records[:3]] == [r["pos"] for r in plain.step_records]
