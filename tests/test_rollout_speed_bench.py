"""The rollout benchmark (benchmarks/rollout_speed.py): a model may name another grounder (``NAME@GROUNDER``), its
rows carry that grounder, and a wrong name fails before any server starts."""

from __future__ import annotations

import json
import sys
from datetime import UTC, datetime
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
rollout_speed = pytest.importorskip("rollout_speed")


def test_a_model_names_its_grounder_or_takes_the_checkpoint_s() -> None:
    assert rollout_speed.split_model("abm_clip_v2") == ("abm_clip_v2", None)
    assert rollout_speed.split_model("abm_clip_v2@tracking") == ("abm_clip_v2", "tracking")
    assert rollout_speed.grounder_of("abm_clip_v2") == "clip"
    assert rollout_speed.grounder_of("abm_oracle_v2") == "oracle"
    assert rollout_speed.grounder_of("abm_clip_v2@tracking") == "tracking"
    with pytest.raises(SystemExit, match="'no_such_model' is not a model of models/index.json"):
        rollout_speed.grounder_of("no_such_model")


def test_one_model_with_two_grounders_gets_a_column_per_grounder() -> None:
    rows = [{"commit": "abc", "model": m, "grounder": g, "stage": "total", "seconds_per_rollout": s}
            for m, g, s in (("abm_clip_v2", "clip", 2.5), ("abm_clip_v2@tracking", "tracking", 1.25))]
    table = rollout_speed.markdown(rows).splitlines()
    assert table[0] == "| stage | clip @ abc | tracking @ abc |"
    assert table[-1] == "| total | 2.50 | 1.25 |"


def test_an_unknown_grounder_fails_before_a_server_starts(monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(rollout_speed, "run", lambda args: pytest.fail("a server started"))
    monkeypatch.setattr(sys, "argv", ["rollout_speed.py", "--models", "abm_clip_v2@psychic"])
    with pytest.raises(SystemExit) as exit_:
        rollout_speed.main()
    assert exit_.value.code == 2
    assert "abm_clip_v2@psychic: unknown grounder 'psychic' (known: " in capsys.readouterr().err


def test_a_recorded_run_is_appended_with_its_time_and_machine(tmp_path: Path) -> None:
    path = tmp_path / "results" / "rollout_speed.json"
    first = [{"commit": "abc", "model": "abm_clip_v2", "grounder": "clip", "stage": "total",
              "seconds_per_rollout": 3.0}]
    rollout_speed.record(path, first, "machine A", datetime(2026, 11, 29, 19, 0, tzinfo=UTC))
    second = [{**first[0], "seconds_per_rollout": 2.0}]  # the same commit and model measured again
    rollout_speed.record(path, second, "machine B", datetime(2026, 11, 30, 8, 5, 9, tzinfo=UTC))
    rows = json.loads(path.read_text())
    assert [(r["seconds_per_rollout"], r["measured"], r["machine"]) for r in rows] == [
        (3.0, "2026-11-29T19:00:00Z", "machine A"), (2.0, "2026-11-30T08:05:09Z", "machine B")]
