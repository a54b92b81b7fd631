"""Closed-loop motion traces: the expert replayed as a policy reaches every keyframe; a grasp pushed into the
table is traced as blocked at the grasp, with its height offset from the expert."""

from __future__ import annotations

import dataclasses
import math

from abm.evaluation.motion_trace import markdown, summarise_traces, trace_rollout
from abm.evaluation.results import eval_seed
from abm.sim.env import make_env, run_expert
from abm.types import KeyframeAction

SEED = eval_seed(0, 0)


def _expert_keyframes() -> list[KeyframeAction]:
    with make_env("pick_block", "seen", SEED, 16) as env:
        return [a for _, a in run_expert(env).steps]


def _replay(actions: list[KeyframeAction]):  # noqa: ANN202 - an ActFn
    queue = iter(actions)
    return lambda obs, instruction, names: next(queue)


def test_the_expert_replayed_reaches_every_keyframe_on_its_own_plan() -> None:
    expert = _expert_keyframes()
    traces = trace_rollout(_replay(expert), "pick_block", "seen", SEED, resolution=16)
    # the episode ends with success at the place, before the expert's retreat
    assert [t.expert_kind for t in traces] == [a.kind for a in expert][:len(traces)]
    assert traces[-1].expert_kind == "place"
    assert all(t.status == "reached" for t in traces)
    assert all(t.expert_cm < 1e-6 and abs(t.expert_dz_cm) < 1e-6 and t.gripper_agrees and t.collision_agrees
               for t in traces)
    assert traces[-1].success and not any(t.success for t in traces[:-1])
    rows = summarise_traces(traces)
    assert sum(r["reached"] for r in rows) == len(traces) and all(r["blocked"] == 0 for r in rows)


def test_a_grasp_pushed_into_the_table_is_traced_as_blocked_there() -> None:
    expert = _expert_keyframes()
    grasp = next(i for i, a in enumerate(expert) if a.kind == "grasp")
    low = expert[grasp].position.copy()
    low[2] = -0.03  # 3 cm under the table top: the fingers stop on it
    actions = list(expert)
    actions[grasp] = dataclasses.replace(expert[grasp], position=low)
    traces = trace_rollout(_replay(actions), "pick_block", "seen", SEED, resolution=16,
                           max_steps=grasp + 1)
    stopped = traces[grasp]
    assert stopped.expert_kind == "grasp" and stopped.status == "blocked"
    assert math.isclose(stopped.expert_dz_cm, 100 * (low[2] - expert[grasp].position[2]), abs_tol=1e-6)
    assert stopped.stop_error_cm > 1.0 and "not reached" in stopped.message
    row = next(r for r in summarise_traces(traces) if r["kind"] == "grasp")
    assert row["blocked"] == 1 and row["stopped_expert_dz_cm"] < 0
    assert "| grasp | 1 | 0 | 1 |" in markdown([row])
