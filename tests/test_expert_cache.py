"""The expert keyframes' disk cache (abm.evaluation.expert_cache): exact round trips, keys that change with the
scene and the code, and a rollout's step records the same whether the expert ran or was read back."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from abm.evaluation import expert_cache
from abm.types import KeyframeAction


def _keyframes() -> tuple[KeyframeAction, ...]:
    rng = np.random.default_rng(3)
    return tuple(KeyframeAction(rng.normal(size=3), rng.normal(size=4), bool(i % 2), bool(i == 1), kind, 4 - 2 * i)
                 for i, kind in enumerate(("grasp", "lift", "move")))


def test_keyframes_read_back_bit_for_bit(tmp_path: Path) -> None:
    stored = _keyframes()
    path = tmp_path / "a" / "b.json"
    expert_cache.write(path, stored)
    back = expert_cache.read(path)
    assert back is not None and len(back) == len(stored)
    for a, b in zip(stored, back, strict=True):
        assert a.position.tobytes() == b.position.tobytes()
        assert a.quaternion.tobytes() == b.quaternion.tobytes()
        assert (a.gripper_open, a.ignore_collision, a.kind, a.symmetry) == (
            b.gripper_open, b.ignore_collision, b.kind, b.symmetry)
    assert [p.name for p in path.parent.iterdir()] == ["b.json"]  # no temporary file left


def test_a_missing_or_damaged_file_reads_as_nothing(tmp_path: Path) -> None:
    assert expert_cache.read(tmp_path / "none.json") is None
    (tmp_path / "bad.json").write_text('[{"position": [0, 0')
    assert expert_cache.read(tmp_path / "bad.json") is None
    (tmp_path / "nan.json").write_text(json.dumps([{"position": [0, 0], "quaternion": [0, 0, 0, 1],
                                                     "gripper_open": True}]))
    assert expert_cache.read(tmp_path / "nan.json") is None


def test_the_file_is_keyed_by_scene_split_file_and_code(tmp_path: Path) -> None:
    splits = tmp_path / "splits.yaml"
    splits.write_text("a: 1\n")
    base = expert_cache.scene_file(tmp_path, "pick_block", "seen", 7, None, "abc")
    assert base == tmp_path / "pick_block" / "seen" / "7-builtin-abc.json"
    others = {expert_cache.scene_file(tmp_path, "pick_block", "unseen", 7, None, "abc"),
              expert_cache.scene_file(tmp_path, "pick_block", "seen", 8, None, "abc"),
              expert_cache.scene_file(tmp_path, "pick_block", "seen", 7, None, "abd"),
              expert_cache.scene_file(tmp_path, "pick_block", "seen", 7, str(splits), "abc")}
    assert base not in others and len(others) == 4
    before = expert_cache.scene_file(tmp_path, "pick_block", "seen", 7, str(splits), "abc")
    splits.write_text("a: 2\n")
    assert expert_cache.scene_file(tmp_path, "pick_block", "seen", 7, str(splits), "abc") != before


@pytest.mark.parametrize("value", ["off", "OFF", "none", ""])
def test_the_cache_switches_off(monkeypatch: pytest.MonkeyPatch, value: str) -> None:
    monkeypatch.setenv(expert_cache.ENV, value)
    assert expert_cache.cache_folder() is None


def test_the_default_folder_is_the_users_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(expert_cache.ENV)
    assert expert_cache.cache_folder() == Path("~/.cache/abm/expert-keyframes").expanduser()


def test_a_rollout_records_the_same_steps_with_the_expert_read_back(monkeypatch: pytest.MonkeyPatch,
                                                                    tmp_path: Path, shared_tiny_run: Path) -> None:
    from sim_helpers import require_simulator

    require_simulator()
    from abm.evaluation import runner
    from abm.evaluation.runner import EvalJob, run_job
    from abm.evaluation.settings import EvalSettings

    monkeypatch.setenv(expert_cache.ENV, str(tmp_path))
    monkeypatch.setattr(runner, "_EXPERTS", {})
    job = EvalJob(str(shared_tiny_run), "abm", "pick_block", "seen", 0, 0, 11, checkpoint=str(shared_tiny_run))
    settings = EvalSettings(resolution=32, max_steps=2)
    first = run_job(job, settings)
    files = list(tmp_path.rglob("*.json"))
    assert len(files) == 1 and files[0].parent == tmp_path / "pick_block" / "seen"
    monkeypatch.setattr(runner, "_EXPERTS", {})  # a new process: only the disk has them

    def no_expert(env: object) -> tuple[KeyframeAction, ...]:
        raise AssertionError("the expert ran although its keyframes were on disk")

    monkeypatch.setattr(runner, "expert_keyframes", no_expert)
    second = run_job(job, settings)
    assert not first.error and not second.error
    assert first.step_records == second.step_records and first.trajectory == second.trajectory
    assert any(r.get("expert") for r in first.step_records)
