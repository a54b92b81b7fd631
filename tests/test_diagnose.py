"""The diagnoses as typed requests: one registry, JSON round trips, and run() writing the file it returns."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from abm.errors import ConfigError
from abm.evaluation import diagnose
from abm.evaluation.diagnose import DIAGNOSES, DiagnosisKind, register_diagnosis
from abm.evaluation.diagnose.keyframe_accuracy import KeyframeAccuracy
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.registry import UnknownNameError

RUN = Path(__file__).parent / "data" / "checkpoints_v1" / "run_oracle"  # a tiny abm (mask) policy


def test_every_diagnosis_is_registered_with_a_request_of_its_kind() -> None:
    assert {"keyframe_accuracy", "skill_text"} <= set(DIAGNOSES.names())
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
    probe = SkillTextProbe(model=Path("m.pt"), task="place_wine", skill_tasks=("pick_block",))
    assert diagnose.from_dict(json.loads(json.dumps(probe.to_dict()))) == probe


def test_a_wrong_request_is_refused_with_what_fits() -> None:
    with pytest.raises(UnknownNameError, match="choose from keyframe_accuracy, skill_text"):
        diagnose.from_dict({"kind": "nope"})
    with pytest.raises(ConfigError, match="unknown key.*episode.*known: models"):
        diagnose.from_dict({"kind": "keyframe_accuracy", "models": ["a"], "tasks": ["b"], "episode": 3})
    with pytest.raises(ConfigError, match="missing"):
        diagnose.from_dict({"kind": "skill_text", "model": "a"})
    with pytest.raises(ConfigError, match="not 'skill_text'"):
        KeyframeAccuracy.from_dict({"kind": "skill_text", "models": ["a"], "tasks": ["b"]})


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
