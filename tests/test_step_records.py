"""Per-step records of evaluation rollouts, the first-unrecovered-error failure rule read from them, the object
each task must hold, and the compressed outcome archive an experiment commits."""

from __future__ import annotations

import lzma
import math

import numpy as np
import pytest

from abm.evaluation.results import (
    EpisodeOutcome,
    eval_seed,
    failure_reason,
    read_outcome_archive,
    write_outcome_archive,
)
from abm.evaluation.step_records import (
    RECOVERY_CM,
    StepRecord,
    episode_failure,
    nearest_expert,
    recovered,
    step_record,
)
from abm.types import KeyframeAction

DOWN = (1.0, 0.0, 0.0, 0.0)  # gripper pointing down, fingers along world -y (x, y, z, w)
TURNED = (0.7071068, 0.7071068, 0.0, 0.0)  # the same, turned 90 degrees about the gripper axis


def step(x: float, y: float, z: float, motion: str = "reached", held: bool = False, open_: bool = True,
         quat: tuple[float, float, float, float] = DOWN) -> StepRecord:
    return StepRecord((x, y, z), quat, open_, motion, held)


APPROACH = step(0.5, 0.0, 0.12)
LOW_GRASP = step(0.5, 0.0, 0.005, "blocked", open_=False)  # 1.5 cm below a 2 cm grasp: pressed into the table


def test_a_grasp_blocked_then_redone_is_recovered_and_the_episode_is_labelled_by_what_went_wrong_last() -> None:
    # the 8-of-12 case: a grasp 1.5 cm low stops, the next step re-does it 1.5 cm higher and holds the block,
    # the policy then loops lift / grasp until the budget ends: it held the object and did not finish
    steps = [APPROACH, LOW_GRASP, step(0.5, 0.0, 0.02, held=True, open_=False),
             step(0.5, 0.0, 0.17, held=True, open_=False), step(0.5, 0.0, 0.02, held=True, open_=False)]
    assert recovered(steps, 1)
    assert episode_failure(False, "", steps) == "timeout"
    # the first edition's rule names any blocked step, recovered or not
    assert failure_reason(False, "", [s.motion for s in steps], True) == "motion blocked"
    # no object held, ever: the recovered stop still does not name the episode
    never = [APPROACH, LOW_GRASP, step(0.5, 0.0, 0.02, open_=False), step(0.5, 0.0, 0.17, open_=False)]
    assert episode_failure(False, "", never) == "grasp missed"


def test_a_redo_must_reach_the_same_pose_with_the_same_gripper_command() -> None:
    def after(redo: StepRecord) -> bool:
        return recovered([APPROACH, LOW_GRASP, redo], 1)

    assert after(step(0.5, 0.0, 0.005 + RECOVERY_CM / 100 - 1e-4, open_=False))
    assert not after(step(0.5, 0.0, 0.005 + RECOVERY_CM / 100 + 1e-3, open_=False))  # too far
    assert not after(step(0.5, 0.0, 0.01, open_=True))  # an approach, not the grasp again
    assert not after(step(0.5, 0.0, 0.01, "blocked", open_=False))  # stopped again
    assert not after(step(0.5, 0.0, 0.01, open_=False, quat=TURNED))  # a grasp across the other axis
    assert after(step(0.5, 0.0, 0.01, open_=False, quat=(0.0, 1.0, 0.0, 0.0)))  # the gripper's 180° turn: same
    assert not recovered([APPROACH, LOW_GRASP], 1)  # the last step: nothing came after it


def test_a_place_blocked_while_carrying_is_not_recovered_by_still_holding() -> None:
    # place_wine: the move lands off the slot, the place goes down onto the rack's wall and stops; the policy
    # loops move / place elsewhere until the budget ends, the bottle in the gripper all along
    carry = dict(held=True, open_=False)
    steps = [APPROACH, step(0.5, 0.0, 0.02, **carry), step(0.5, 0.0, 0.17, **carry),
             step(0.6, 0.2, 0.25, **carry), step(0.6, 0.2, 0.1, "blocked", **carry),
             step(0.62, 0.15, 0.25, **carry), step(0.62, 0.15, 0.12, "blocked", **carry)]
    assert not recovered(steps, 4)
    assert episode_failure(False, "", steps) == "motion blocked"


def test_the_holding_restored_or_the_grasp_completed_recover_a_stop() -> None:
    carry = dict(held=True, open_=False)
    # a blocked carry knocks the object out of the gripper; the policy grasps it again later
    dropped = [step(0.5, 0.0, 0.02, **carry), step(0.6, 0.1, 0.1, "blocked", open_=False),
               step(0.55, 0.05, 0.12), step(0.55, 0.05, 0.02, **carry)]
    assert recovered(dropped, 1) and episode_failure(False, "", dropped) == "timeout"
    assert not recovered(dropped[:3], 1)  # never held again
    # a blocked grasp, then a grasp 3 cm away (not a re-do) that gets the object
    regrasp = [APPROACH, LOW_GRASP, step(0.53, 0.0, 0.02, **carry)]
    assert recovered(regrasp, 1)
    # a grasp that touched a neighbour on the way (collided) but closed on the object
    touched = [APPROACH, step(0.5, 0.0, 0.02, "collided", **carry), step(0.5, 0.0, 0.17, **carry)]
    assert recovered(touched, 1) and episode_failure(False, "", touched) == "timeout"


def test_the_reason_is_the_first_stop_not_recovered_from_in_step_order() -> None:
    steps = [APPROACH, LOW_GRASP, step(0.5, 0.0, 0.02, held=True, open_=False),
             step(0.7, 0.2, 0.3, "collided", held=True, open_=False),
             step(0.9, 0.4, 0.5, "unreachable", held=True, open_=False)]
    assert episode_failure(False, "", steps) == "collision"  # the blocked grasp was recovered from
    assert failure_reason(False, "", [s.motion for s in steps], True) == "IK unreachable"  # the old precedence
    assert episode_failure(True, "", steps) == ""
    assert episode_failure(False, "RuntimeError: boom", steps) == "crashed"
    assert episode_failure(False, "", []) == "grasp missed"


def test_step_records_are_compact_json_and_read_back() -> None:
    action = KeyframeAction(np.array([0.51234567, -0.1, 0.02]), np.array(TURNED), False, True)
    expert = [KeyframeAction(np.array([0.5, -0.1, 0.12]), np.array(DOWN), True, kind="approach"),
              KeyframeAction(np.array([0.5, -0.1, 0.02]), np.array(DOWN), False, True, kind="grasp")]
    index, cm, deg = nearest_expert(action, expert)
    assert index == 1 and cm == pytest.approx(1.234567) and deg == pytest.approx(90.0, abs=1e-4)
    assert nearest_expert(action, [])[0] == -1
    record = step_record(action, "unreachable", False, math.nan, expert, {"found": True, "confidence": 1.0})
    data = record.to_json()
    assert data == {"pos": [0.5123, -0.1, 0.02], "quat": [0.7071, 0.7071, 0.0, 0.0], "yaw": 0.0, "open": False,
                    "straight": True, "motion": "unreachable", "stop_cm": None, "held": False, "expert": "grasp",
                    "expert_i": 1, "expert_cm": 1.2, "expert_deg": 90.0,
                    "grounding": {"found": True, "confidence": 1.0}}
    back = StepRecord.from_json(data)
    assert (back.expert_kind, back.motion, back.gripper_open, back.grounding) == ("grasp", "unreachable", False,
                                                                                 {"found": True, "confidence": 1.0})
    assert StepRecord.from_json(back.to_json()) == back
    assert step(0.5, 0.0, 0.1).yaw_deg == pytest.approx(-90.0)  # 180° about x: the fingers along world -y
    assert "grounding" not in step_record(action, "reached", True, 0.001, expert).to_json()  # no mask: no key


def test_outcome_archive_round_trip(tmp_path) -> None:
    records = [step(0.5, 0.0, 0.1).to_json(), LOW_GRASP.to_json()]
    outcomes = [EpisodeOutcome("rvt", "insert_peg", "seen", 0, 1, eval_seed(0, 1), False, 2, failure="grasp missed",
                               step_records=records),
                EpisodeOutcome("abm", "insert_peg", "seen", 0, 0, eval_seed(0, 0), True, 6, trajectory="ab" * 8)]
    path = write_outcome_archive(outcomes, tmp_path / "abm_seen_outcomes.jsonl.xz")
    assert path.read_bytes()[:6] == b"\xfd7zXZ\x00"  # xz
    back = read_outcome_archive(path)
    assert back == sorted(outcomes, key=lambda o: o.method)  # protocol order: method first
    assert [StepRecord.from_json(r) for r in back[1].step_records][1] == LOW_GRASP
    first = path.read_bytes()
    write_outcome_archive(reversed(outcomes), path)
    assert path.read_bytes() == first  # the same outcomes, the same bytes
    assert lzma.decompress(first).decode().count("\n") == 2


def test_each_task_declares_the_object_its_gripper_must_hold() -> None:
    from abm.sim.tasks import TASKS, get_task

    # every other task carries its instruction's target (each instance names it: info["target"])
    assert {name: TASKS[name].held_role for name in TASKS.names() if TASKS[name].held_role != "target"} == {
        "insert_peg": "ring", "close_jar": "lid"}
    for name, carried in (("insert_peg", "ring"), ("close_jar", "jar lid")):
        task = get_task(name)
        instance = task.sample(eval_seed(0, 0), "seen")
        held = task.held_object(instance)
        assert held is not None and held != instance.info["target"]
        assert instance.scene.objects[held].name == carried


def test_insert_peg_rollouts_check_the_ring_in_the_gripper() -> None:
    """The expert as the policy: the ring is held from the grasp until the drop, so the episode held its object
    (the peg, checked before, never is)."""
    from sim_helpers import require_simulator

    require_simulator()
    from abm.sim.env import make_env, run_policy

    with make_env("insert_peg", "seen", eval_seed(0, 0), 32) as env:
        env.reset()
        expert = env.expert_actions()
        episode = run_policy(env, lambda obs: next(expert))
    assert episode.success and episode.metadata["held_target"]
    # approach, grasp, lift, move, place (the ring around the peg: done)
    assert episode.metadata["held"] == [False, True, True, True, False]
    assert len(episode.metadata["stop_errors"]) == 5 and max(episode.metadata["stop_errors"]) < 0.01


def test_rollouts_record_every_step_against_the_expert_and_archive_the_outcomes(shared_tiny_run, tmp_path) -> None:
    from sim_helpers import require_simulator

    require_simulator()
    from abm.evaluation import runner
    from abm.evaluation.results import OUTCOME_ARCHIVE, OutcomeLog
    from abm.sim.env import make_env, run_expert

    settings = runner.EvalSettings(max_steps=2, resolution=32)
    job = runner.EvalJob(str(shared_tiny_run), "abm", "pick_block", "seen", 0, 0, eval_seed(0, 0))
    outcome = runner.run_job(job, settings)
    assert outcome.error == "" and len(outcome.step_records) == outcome.steps >= 1
    records = [StepRecord.from_json(r) for r in outcome.step_records]
    assert outcome.failure == episode_failure(outcome.success, "", records)
    with make_env("pick_block", "seen", eval_seed(0, 0), 32) as env:  # the demonstration generator's keyframes
        labels = [label for _, label in run_expert(env).steps]
    for record in records:
        action = KeyframeAction(np.array(record.position), np.array(record.quaternion), record.gripper_open)
        index, cm, _ = nearest_expert(action, labels)
        assert (record.expert_index, record.expert_kind) == (index, labels[index].kind)
        assert record.expert_cm == pytest.approx(cm, abs=0.06)  # rounded to 0.1 cm from the unrounded pose
        assert record.grounding is not None and record.grounding["found"] is True  # the oracle finds the block
        assert record.motion in ("reached", "blocked", "unreachable", "collided")
    assert outcome.grounding == [r.grounding for r in records]

    def replay(job: runner.EvalJob, settings: runner.EvalSettings) -> EpisodeOutcome:
        return EpisodeOutcome(job.method, job.task, job.split, job.repeat, job.episode, job.seed, False,
                              outcome.steps, checkpoint=job.checkpoint, settings=job.settings,
                              step_records=outcome.step_records)

    out = tmp_path / "ev"
    runner.evaluate([shared_tiny_run], ["pick_block"], "seen", out, episodes=2, repeats=1, settings=settings,
                    progress=False, runner=replay)
    archived = read_outcome_archive(out / OUTCOME_ARCHIVE)
    assert archived == OutcomeLog(out / "outcomes.jsonl").read() and len(archived) == 2
    assert archived[1].step_records == outcome.step_records
