"""The diagnoses as typed requests: one registry, JSON round trips, and run() writing the file it returns."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from abm.errors import ConfigError
from abm.evaluation import diagnose
from abm.evaluation.diagnose import DIAGNOSES, DiagnosisKind, register_diagnosis
from abm.evaluation.diagnose.failure_reasons import FailureReasons
from abm.evaluation.diagnose.keyframe_accuracy import KeyframeAccuracy
from abm.evaluation.diagnose.rotation_fit import RotationFit, read_rows
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.registry import UnknownNameError

RUN = Path(__file__).parent / "data" / "checkpoints_v1" / "run_oracle"  # a tiny abm (mask) policy


def test_every_diagnosis_is_registered_with_a_request_of_its_kind() -> None:
    assert DIAGNOSES.names() == ("keyframe_accuracy", "skill_text", "rotation_fit", "failure_reasons",
                                 "destination_grounding")
    for name, entry in DIAGNOSES.items():
        assert entry.request_class().kind == name


def test_a_request_round_trips_through_json() -> None:
    request = KeyframeAccuracy(models=(Path("models/abm_oracle_v2.pt"),), tasks=("pick_block", "place_wine"),
                               out=Path("runs/x/keyframe_accuracy/abm_oracle.json"), splits=("seen",), steps=(500,),
                               grounder="oracle")
    data = json.loads(json.dumps(request.to_dict()))
    assert data["kind"] == "keyframe_accuracy" and data["models"] == ["models/abm_oracle_v2.pt"]
    again = diagnose.from_dict(data)
    assert again == request and isinstance(again.models[0], Path) and again.steps == (500,)
    for other in (SkillTextProbe(model=Path("m.pt"), task="place_wine", skill_tasks=("pick_block",)),
                  RotationFit(model=Path("m.pt"), data=Path("d"), tasks=("place_food",), probe=Path("p.json"),
                              arm="two-stage", step=1000),
                  RotationFit(model=Path("m.pt"), data=Path("d")),
                  FailureReasons(models=(Path("a.pt"), Path("b.pt")), tasks=("pick_block",), split="unseen")):
        assert diagnose.from_dict(json.loads(json.dumps(other.to_dict()))) == other


def test_a_wrong_request_is_refused_with_what_fits() -> None:
    with pytest.raises(UnknownNameError, match="choose from keyframe_accuracy, skill_text, rotation_fit"):
        diagnose.from_dict({"kind": "nope"})
    with pytest.raises(ConfigError, match="unknown key.*episode.*known: models"):
        diagnose.from_dict({"kind": "keyframe_accuracy", "models": ["a"], "tasks": ["b"], "episode": 3})
    with pytest.raises(ConfigError, match="missing"):
        diagnose.from_dict({"kind": "skill_text", "model": "a"})
    with pytest.raises(ConfigError, match="not 'skill_text'"):
        KeyframeAccuracy.from_dict({"kind": "skill_text", "models": ["a"], "tasks": ["b"]})
    with pytest.raises(ConfigError, match="needs its arm and step"):
        RotationFit(model=Path("m.pt"), data=Path("d"), probe=Path("p.json"), arm="two-stage")


def test_a_new_diagnosis_is_one_registry_entry() -> None:
    register_diagnosis("probe_again", DiagnosisKind("abm.evaluation.diagnose.skill_text:SkillTextProbe", "test"))
    try:
        assert DIAGNOSES["probe_again"].request_class() is SkillTextProbe
    finally:
        DIAGNOSES.unregister("probe_again")


def test_keyframe_accuracy_writes_what_it_returns(tmp_path: Path) -> None:
    out = tmp_path / "diag" / "abm.json"
    payload = KeyframeAccuracy(models=(RUN,), tasks=("pick_block",), out=out, splits=("seen",), episodes=1,
                               resolution=32, steps=(1, 7)).run()
    assert json.loads(out.read_text()) == payload
    assert set(payload["checkpoints"]) == {"abm", "abm@1"}  # step 7 has no checkpoint: skipped
    assert payload["grounder"] == "checkpoint's" and payload["episodes"] == 1
    kinds = {row["kind"] for row in payload["summary"] if row["method"] == "abm"}
    assert {"grasp", "lift"} <= kinds
    assert len(payload["errors"]) == 2 * sum(row["n"] for row in payload["summary"] if row["method"] == "abm")


def test_the_skill_text_probe_writes_one_row_per_skill_text(tmp_path: Path) -> None:
    out = tmp_path / "probe.json"
    payload = SkillTextProbe(model=RUN, task="pick_block", skill_tasks=("pick_block", "place_food"), out=out,
                             keyframe="grasp", episodes=1, resolution=32).run()
    assert json.loads(out.read_text()) == payload
    assert payload["kind"] == "grasp" and payload["run"] == str(RUN)
    assert [r["task"] for r in payload["rows"]] == ["pick_block", "place_food"]
    assert [r["own"] for r in payload["rows"]] == [True, False]


def test_the_rotation_fit_writes_its_rows_and_a_probe_s_fit(shared_tiny_run: Path, tmp_path: Path) -> None:
    from abm.data.episode_store import save_episode
    from abm.train.synthetic import synthetic_episode

    for seed in range(2):
        save_episode(synthetic_episode(seed, 32), tmp_path / "data" / "pick_block" / "seen" / f"episode_{seed}.h5")
    probe = tmp_path / "probe.json"
    probe.write_text(json.dumps({"fit": [{"arm": "two-stage", "step": 5, "augment": False}], "accuracy": [1],
                                 "rollouts": [2]}))
    request = RotationFit(model=shared_tiny_run, data=tmp_path / "data", out=tmp_path / "fit.json", probe=probe,
                          arm="single-stage", step=2)
    records = request.run()
    assert json.loads((tmp_path / "fit.json").read_text()) == json.loads(json.dumps(records))
    assert [r["augment"] for r in records] == [False] * (len(records) // 2) + [True] * (len(records) // 2)
    assert read_rows(tmp_path / "fit.json") == request.measure()  # the same rows, measured again or read back
    written = json.loads(probe.read_text())
    assert written["accuracy"] == [1] and written["rollouts"] == [2]  # the probe's other lists are kept
    ours = [r for r in written["fit"] if r["arm"] == "single-stage"]
    assert len(ours) == len(records) and all(r["step"] == 2 and "yaw_ce" in r for r in ours)
    assert any(r["arm"] == "two-stage" for r in written["fit"])  # another arm's rows stay


def test_failure_reasons_trace_every_step_of_each_rollout(tmp_path: Path) -> None:
    out = tmp_path / "traces.json"
    payload = FailureReasons(models=(RUN,), tasks=("pick_block",), out=out, episodes=1).run()
    assert json.loads(out.read_text()) == json.loads(json.dumps(payload))  # tuples written as lists
    found = payload["methods"]["abm"]["pick_block"]
    assert found["steps"] and {"status", "expert_kind", "stop_error_cm"} <= set(found["steps"][0])
    assert found["successes"] in (0, 1)
