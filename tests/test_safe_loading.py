"""No file abm reads can run code: one crafted payload per loader.

Each payload would create a marker file if the loader executed it (a pickle whose ``__reduce__`` calls
``Path.touch``, a YAML ``!!python/object/apply`` tag); every test checks the loader refuses with its own
error and that the marker was never created.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from abm.cli import main as cli_main


class _Payload:
    """Unpickling this calls ``Path.touch`` on the marker: what a crafted file could do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return Path.touch, (Path(self.marker),)


def _yaml_payload(marker: Path) -> str:
    return f"!!python/object/apply:os.system ['touch {marker}']\n"


@pytest.fixture
def marker(tmp_path):
    path = tmp_path / "pwned"
    yield path
    assert not path.exists(), "a crafted file ran code"


def test_the_payloads_do_run_code_when_loaded_unsafely(tmp_path) -> None:
    """The payloads are real: the unsafe loaders would execute them."""
    import yaml

    pickle.loads(pickle.dumps(_Payload(tmp_path / "a")))
    assert (tmp_path / "a").exists()
    yaml.unsafe_load(_yaml_payload(tmp_path / "b"))
    assert (tmp_path / "b").exists()


def test_policy_checkpoint(tmp_path, marker) -> None:
    from abm.policy.checkpoint import load_checkpoint

    bad = tmp_path / "evil.pt"
    torch.save({"format": "abm-policy", "version": 1, "x": _Payload(marker)}, bad)
    with pytest.raises(ValueError, match="refusing to load .*evil.pt.*crafted"):
        load_checkpoint(bad)


def test_clip_training_checkpoint(tmp_path, marker, capsys) -> None:
    from abm.clip_training.train import CHECKPOINT, load_training_state

    bad = tmp_path / CHECKPOINT
    torch.save({"model": {}, "history": [_Payload(marker)]}, bad)
    with pytest.raises(ValueError, match="refusing to load .*checkpoint.pt.*crafted"):
        load_training_state(bad)
    plain = tmp_path / "plain.pt"
    torch.save({"model": {}}, plain)
    with pytest.raises(ValueError, match="not an abm CLIP training checkpoint .*missing optimizer"):
        load_training_state(plain)
    # abm clip train --resume refuses it before rendering any data
    assert cli_main(["clip", "train", "--out", str(tmp_path), "--resume", "--shards", "1"]) == 2
    assert "refusing to load" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


def test_episode_file(tmp_path, marker) -> None:
    from abm.data.episode_store import EpisodeFormatError, load_episode, read_info

    bad = tmp_path / "seen_00000.h5"
    bad.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(EpisodeFormatError):
        load_episode(bad)
    with pytest.raises(EpisodeFormatError):
        read_info(bad)


def test_split_file(tmp_path, marker) -> None:
    from abm.sim.splits import SplitFileError, load_splits

    bad = tmp_path / "splits.yaml"
    bad.write_text(_yaml_payload(marker))
    with pytest.raises(SplitFileError, match="splits.yaml: not a valid split file"):
        load_splits(bad)
    bad.write_text("version: 1\ntasks:\n  pick_block:\n    seen: " + _yaml_payload(marker))
    with pytest.raises(SplitFileError):
        load_splits(bad)


def test_robot_file(tmp_path, marker, capsys) -> None:
    from abm.robot.run import RobotConfig

    bad = tmp_path / "robot.yaml"
    bad.write_text("limits: {max_step_m: " + _yaml_payload(marker).strip() + "}\n")
    with pytest.raises(ValueError, match="robot.yaml: not a valid robot file"):
        RobotConfig.load(bad)
    assert cli_main(["run", "--robot", str(bad), "--run", str(tmp_path)]) == 2
    assert "abm: error: " in capsys.readouterr().err


def test_calibration_file(tmp_path, marker) -> None:
    from abm.robot.calibration import load_calibration

    bad = tmp_path / "calibration.yaml"
    bad.write_text("cameras: " + _yaml_payload(marker))
    with pytest.raises(ValueError, match="calibration.yaml: not a valid calibration file"):
        load_calibration(bad)


def test_template_file(tmp_path, marker) -> None:
    from abm.language.instruction import load_templates

    bad = tmp_path / "templates.yaml"
    bad.write_text("skills: " + _yaml_payload(marker))
    with pytest.raises(ValueError, match="templates.yaml: not a valid template file"):
        load_templates(bad)


def test_grounding_cache_entry(tmp_path, marker) -> None:
    from abm.grounding.cache import GroundingCache

    cache = GroundingCache(tmp_path / "cache")
    cache.put("k", {"mask": np.ones(3)})
    assert cache.get("k") is not None
    fresh = GroundingCache(tmp_path / "cache")
    path = next((tmp_path / "cache").rglob("*.npz"))
    np.savez(path, mask=np.array([_Payload(marker)], dtype=object))
    assert fresh.get("k") is None  # a pickled entry is a miss, never unpickled


def test_camera_recording(tmp_path, marker) -> None:
    from abm.robot.devices import ReplayCamera

    (tmp_path / "meta.json").write_text(json.dumps({"steps": 1, "cameras": ["front"]}))
    np.savez(tmp_path / "step_000.npz", **{"front/rgb": np.array([_Payload(marker)], dtype=object)})
    with pytest.raises(ValueError, match="allow_pickle"):
        ReplayCamera(tmp_path).read()


def test_clip_dataset_shard(tmp_path, marker) -> None:
    from abm.clip_training.data import META, load_dataset, shard_path

    (tmp_path / META).write_text(json.dumps({"classes": ["a"]}))
    np.savez(shard_path(tmp_path, 0), images=np.array([_Payload(marker)], dtype=object))
    with pytest.raises(ValueError, match="allow_pickle"):
        load_dataset(tmp_path)


def test_no_unsafe_loader_in_the_package() -> None:
    import abm

    root = Path(abm.__file__).parent
    for path in root.rglob("*.py"):
        text = path.read_text()
        for needle in ("weights_only=False", "allow_pickle=True", "yaml.load(", "unsafe_load", "pickle.load"):
            assert needle not in text, f"{path.relative_to(root)} uses {needle}"


def test_training_grounding_cache_entry(tmp_path, marker) -> None:
    from abm.data.keyframes import KeyframeDataset
    from abm.geometry import Workspace
    from abm.train.synthetic import synthetic_episodes

    ds = KeyframeDataset(synthetic_episodes(1, 32), Workspace(), {"kind": "clip", "model": "tiny"}, mask=True,
                         augment=False, cache_dir=tmp_path / "cache", require_cache=False)
    path = ds._cache_file(0, 0)
    path.parent.mkdir(parents=True)
    np.savez(path, mask=np.array([_Payload(marker)], dtype=object), heatmap=np.zeros(1))
    with pytest.raises(ValueError, match="allow_pickle"):
        ds[0]


# ---- duplicate keys: YAML keeps the last one silently, abm refuses ------------------------------------------
def test_a_key_given_twice_is_refused_in_every_yaml_file(tmp_path, capsys) -> None:
    """Two ``limits:`` sections (or a key twice inside one) in any file abm reads: one error naming the file, the
    key and both lines, never a silent choice of the last one."""
    from abm.files import DuplicateKeyError, load_yaml
    from abm.language.instruction import load_templates
    from abm.robot.calibration import load_calibration
    from abm.robot.run import RobotConfig
    from abm.sim.splits import SplitFileError, load_splits

    robot = tmp_path / "robot.yaml"
    robot.write_text("limits: {max_step_m: 0.1}\narm: {kind: dry-run}\nlimits: {max_step_m: 2.0}\n")
    with pytest.raises(DuplicateKeyError, match=r"robot.yaml: the key 'limits' appears twice in one section of the "
                                                r"robot file \(lines 1 and 3\)"):
        RobotConfig.load(robot)
    assert cli_main(["run", "--robot", str(robot), "--run", str(tmp_path), "--instruction", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"abm: error: {robot}: the key 'limits' appears twice")
    assert "remove or merge one of them" in err[0]
    robot.write_text("limits:\n  max_step_m: 0.1\n  max_tilt_deg: 30\n  max_step_m: 2.0\n")  # inside a section
    with pytest.raises(ValueError, match=r"the key 'max_step_m' appears twice .*\(lines 2 and 4\)"):
        RobotConfig.load(robot)
    calibration = tmp_path / "calibration.yaml"
    calibration.write_text("cameras:\n  front: {}\n  front: {}\n")
    with pytest.raises(ValueError, match="calibration.yaml: the key 'front' appears twice .*calibration file"):
        load_calibration(calibration)
    splits = tmp_path / "splits.yaml"
    splits.write_text("version: 1\ntasks: {}\nversion: 1\n")
    with pytest.raises(SplitFileError, match="splits.yaml: the key 'version' appears twice .*split file"):
        load_splits(splits)
    templates = tmp_path / "templates.yaml"
    templates.write_text("synonyms: {}\nskills: []\nsynonyms: {}\n")
    with pytest.raises(ValueError, match="templates.yaml: the key 'synonyms' appears twice .*template file"):
        load_templates(templates)
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("steps: 3\nlr: 0.01\nsteps: 300\n")
    with pytest.raises(SystemExit):
        cli_main(["train", "--config", str(recipe), "--synthetic", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{recipe}: the key 'steps' appears twice in one section of the recipe (lines 1 and 3)" \
        in err[0] and not (tmp_path / "run").exists()
    # still plain YAML: the same key in two sections, repeated list items, and merge keys (an override on purpose)
    ok = tmp_path / "ok.yaml"
    ok.write_text("a: {x: 1}\nb: {x: 1}\nc: [{x: 1}, {x: 1}]\nbase: &b {x: 1, y: 2}\nd:\n  <<: *b\n  x: 3\n")
    assert load_yaml(ok, "file") == {"a": {"x": 1}, "b": {"x": 1}, "c": [{"x": 1}, {"x": 1}],
                                     "base": {"x": 1, "y": 2}, "d": {"x": 3, "y": 2}}


def test_every_yaml_file_is_read_through_the_one_strict_loader() -> None:
    """No module but abm.files parses YAML itself (so no file escapes the duplicate-key check)."""
    import abm

    root = Path(abm.__file__).parent
    for path in root.rglob("*.py"):
        if path.name == "files.py" and path.parent == root:
            continue
        text = path.read_text()
        for needle in ("safe_load(", "SafeLoader", "yaml.load", "full_load("):
            assert needle not in text, f"{path.relative_to(root)} parses YAML itself ({needle}): use abm.files"
