"""Checkpoints and run folders written before the typed grounder configurations still load and resume.

``tests/data/checkpoints_v1`` was written by the code of commit 5b86c96 (``generate.py`` there), when the
grounder was a plain dict everywhere: a tiny oracle-grounded run, a CLIP-grounded run (``mode``/``threshold``
options) and an exported checkpoint with a tracking grounder in the old shortcut keys (``scoring``). Today's
code must read their grounder as the typed configuration equal to what was saved, predict what they predicted
then, and resume their run folders without calling the settings changed.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from abm.grounding.config import (
    ClipGrounderConfig,
    OracleGrounderConfig,
    TrackingGrounderConfig,
    build_grounder,
    grounder_config_from_dict,
)
from abm.policy import KeyframePolicy
from abm.policy.config import PolicyConfig
from abm.train import TrainConfig, train
from abm.train.synthetic import synthetic_episodes

DATA = Path(__file__).parent / "data" / "checkpoints_v1"
EXPECTED = json.loads((DATA / "expected.json").read_text())
SOURCES = {"oracle": (DATA / "run_oracle", OracleGrounderConfig),
           "clip": (DATA / "run_clip", ClipGrounderConfig),
           "tracking": (DATA / "tracking.pt", TrackingGrounderConfig)}


@pytest.fixture(scope="module")
def episode():
    return synthetic_episodes(1, camera_resolution=32)[0]


def test_fixture_files_are_small() -> None:
    for path in DATA.rglob("*.pt"):
        assert path.stat().st_size < 300 * 1024, path


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_old_checkpoint_loads_typed_and_predicts_the_same(name, episode) -> None:
    path, cls = SOURCES[name]
    saved = EXPECTED[name]["grounder"]
    stored = torch.load(next(iter(sorted(path.rglob("*.pt")))) if path.is_dir() else path, weights_only=True)
    assert stored["grounder"] == saved  # the file holds the old dict form
    policy = KeyframePolicy.from_checkpoint(path)
    assert isinstance(policy.grounder_config, cls)
    assert policy.grounder_config == grounder_config_from_dict(saved)
    assert policy.grounder_config.to_dict() == saved  # written back unchanged
    obs, _ = episode.steps[0]
    seen = policy.explain(obs, episode.instruction, episode.object_names)
    want = EXPECTED[name]
    np.testing.assert_allclose(seen.action.position, want["position"], atol=1e-5)
    assert abs(float(np.dot(seen.action.quaternion, want["quaternion"]))) == pytest.approx(1.0, abs=1e-5)
    assert bool(seen.action.gripper_open) == want["gripper_open"]
    h = seen.heatmaps
    weighted = float(np.sum(h * np.arange(h.size).reshape(h.shape) / h.size))  # a fingerprint of all heatmaps
    assert weighted == pytest.approx(want["heatmap_sum"], rel=1e-4)
    assert float(seen.sample["point_mask"].sum()) == pytest.approx(want["point_mask_sum"])


def test_old_grounder_dicts_read_typed() -> None:
    clip = grounder_config_from_dict(EXPECTED["clip"]["grounder"])
    assert clip == ClipGrounderConfig(model="tiny", device="cpu", mode="field", threshold=0.3)
    tracking = grounder_config_from_dict(EXPECTED["tracking"]["grounder"])
    assert isinstance(tracking, TrackingGrounderConfig) and tracking.radius == 0.02
    assert tracking.inner.proposals.scoring == "combined" and tracking.inner.normalization == "minmax"
    # the defaults named or left out: the same configuration
    assert grounder_config_from_dict({"kind": "clip", "mode": "proposals"}) == ClipGrounderConfig()
    assert grounder_config_from_dict({}) == OracleGrounderConfig()  # no kind: the oracle, as always
    assert grounder_config_from_dict({"kind": "tracking", "inner": "clip"}).inner == ClipGrounderConfig()
    with pytest.raises(ValueError, match="unknown grounder kind 'sam'"):
        grounder_config_from_dict({"kind": "sam"})
    with pytest.raises(ValueError, match=r"\['colour'\]"):
        grounder_config_from_dict({"kind": "clip", "colour": "red"})
    with pytest.raises(ValueError, match=r"proposals\.vox"):
        grounder_config_from_dict({"kind": "clip", "proposals": {"vox": 0.1}})
    with pytest.raises(ValueError, match="oracle"):
        grounder_config_from_dict({"kind": "oracle", "model": "tiny"})
    with pytest.raises(ValueError, match="mode"):
        ClipGrounderConfig(mode="boxes")
    assert build_grounder(OracleGrounderConfig()).name == "oracle"


def _copy_run(name: str, dest: Path) -> Path:
    run = dest / name
    shutil.copytree(DATA / name, run)
    return run


def _saved_config(run: Path, **changes) -> TrainConfig:
    """The options of an old run's config.json (the flat form: grounder, grounder_options, language), as read
    today, with ``changes`` to the saved (flat) values."""
    saved = json.loads((run / "config.json").read_text())["train"]
    assert isinstance(saved["grounder"], str) and "grounder_options" in saved  # the old flat form
    saved.update(out=run, cache_dir=run / "cache", resume=True, steps=2, progress=False, **changes)
    return TrainConfig.from_dict(saved)


def test_old_run_folders_resume(episode, tmp_path) -> None:
    episodes = [episode]
    run = _copy_run("run_clip", tmp_path)
    # the saved options, and the same ones written with a default named: not "other settings"
    same = {**json.loads((run / "config.json").read_text())["train"]["grounder_options"], "dense_mode": "maskclip"}
    summary = train(_saved_config(run, grounder_options=same), episodes)
    assert summary["steps"] == 2
    resumed = TrainConfig.from_dict(json.loads((run / "config.json").read_text())["train"])  # now the nested form
    assert resumed.grounder.to_dict() == {**EXPECTED["clip"]["grounder"], "dense_mode": "maskclip"}
    ckpt = torch.load(run / "checkpoints/step_00000002.pt", weights_only=True)
    assert TrainConfig.from_dict(ckpt["train_config"]) == resumed  # what config.json says, the checkpoint holds
    assert resumed.policy == PolicyConfig.from_dict(ckpt["policy_config"])  # the network it trained
    run2 = _copy_run("run_clip", tmp_path / "b")
    other = {**json.loads((run2 / "config.json").read_text())["train"]["grounder_options"], "threshold": 0.5}
    with pytest.raises(ValueError, match="other settings"):
        train(_saved_config(run2, grounder_options=other), episodes)
    # the oracle run from its recipe.yaml, through the CLI
    from abm.cli import main as cli_main

    run3 = _copy_run("run_oracle", tmp_path)
    recipe = yaml.safe_load((run3 / "recipe.yaml").read_text())
    assert recipe["grounder"] == "oracle"
    code = cli_main(["train", "--config", str(run3 / "recipe.yaml"), "--out", str(run3), "--resume", "--steps", "2",
                     "--synthetic", "1", "--camera-resolution", "32", "--no-progress"])
    assert code == 0
    assert (run3 / "checkpoints" / "step_00000002.pt").is_file()
