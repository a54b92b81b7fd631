"""One typed run config: TrainConfig nests the network's PolicyConfig, reads every older form, is what a spec's run
trains (ExperimentSpec.train_config) and what the report reads back from RUN/config.json."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from abm.errors import ConfigError
from abm.experiments.report.runs import describe_run
from abm.experiments.spec import load_spec
from abm.experiments.state import Layout
from abm.grounding.config import ClipGrounderConfig
from abm.policy.config import PolicyConfig
from abm.train.config import TrainConfig


def test_the_policy_is_the_presets_with_the_changes_given() -> None:
    cfg = TrainConfig(method="rvt", preset="small", policy={"resolution": 64})  # a recipe's or a spec's policy:
    assert cfg.policy == PolicyConfig.from_preset("small", "rvt", resolution=64)
    assert cfg.policy.preset == "small+custom" and cfg.policy.preset_changes() == {"resolution": 64}
    assert TrainConfig(method="rvt", preset="paper").policy == PolicyConfig.from_preset("paper", "rvt")  # left out
    assert cfg.to_recipe()["policy"] == {"resolution": 64}  # RUN/recipe.yaml: the changes, as abm train reads them
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg and cfg.to_dict()["policy"]["resolution"] == 64
    with pytest.raises(ConfigError, match="policy: the network of variant abm and preset paper, but method rvt"):
        TrainConfig(method="rvt", policy=PolicyConfig.from_preset("paper", "abm"))
    with pytest.raises(ConfigError, match=r"policy: unknown field\(s\) resolutoin"):
        TrainConfig(policy={"resolutoin": 64})
    with pytest.raises(ConfigError, match="policy: patch_size 6 must divide the view resolution 64"):
        TrainConfig(policy={"resolution": 64, "patch_size": 6})


def test_a_config_json_of_an_older_run_reads_as_the_same_config() -> None:
    new = TrainConfig(method="abm", policy={"resolution": 64, "rotation_crop": 16}, grounder="clip")
    old = {k: v for k, v in new.to_dict().items() if k != "policy"}
    old.update(policy_overrides={"resolution": 64, "rotation_crop": 16}, grounder="clip", grounder_options={
        "model": ClipGrounderConfig().model})  # written before the policy and the grounder were typed
    assert TrainConfig.from_dict(old) == new


def test_a_spec_run_trains_its_typed_config_with_the_engines_folders(tmp_path: Path) -> None:
    spec = load_spec("paper_tables")
    layout = Layout.of(spec, tmp_path)
    cfg = spec.train_config("abm_clip", layout)
    assert (cfg.out, cfg.data, cfg.cache_dir) == (Path("runs/paper/abm_clip"), Path("runs/paper/data"),
                                                  Path("runs/paper/cache_masks"))  # root-relative, as jobs run
    assert cfg.resume and not cfg.progress and cfg.steps == 5000 and cfg.method == "abm"
    assert cfg.grounder.clip_options() == {"model": "models/benchmark-clip"} and cfg.policy.resolution == 64
    assert TrainConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg  # what a job file carries
    assert spec.train_config("abm_clip", layout, "tiny").grounder.clip_options() == {"model": "tiny"}
    oracle = spec.train_config("abm_oracle", layout, "tiny")  # no CLIP to replace, no grounding cache
    assert oracle.grounder.kind == "oracle" and oracle.cache_dir is None
    ifd = spec.runs["ifd_clip"]
    assert ifd.cache == "features" and spec.train_config("ifd_clip", layout).cache_dir == Path(
        "runs/paper/cache_features")


def test_the_report_reads_a_run_through_its_config(tmp_path: Path) -> None:
    trained = TrainConfig(method="abm", data=Path("runs/x/data"), steps=30, policy={
        "resolution": 64, "zoom_size": 0.3, "workspace_size": 0.6, "lang_dim": 128})
    (tmp_path / "config.json").write_text(json.dumps({"train": trained.to_dict(), "lr": 1e-3, "warmup": 50,
                                                       "language": {"kind": "hash", "dim": 128}}))
    entry = describe_run(tmp_path)
    assert (entry["data"], entry["steps"], entry["language"]) == ("runs/x/data", 30, "hash")
    assert entry["recipe"] == {"batch": 8, "optimizer": "adamw", "warmup": 50, "weight_decay": 1e-4, "seed": 0,
                               "lr": 1e-3, "resolution": 64, "patch_size": 8, "preset": "small+custom",
                               "workspace_size": 0.6, "zoom_size": 0.3, "zoom_resolution": 32, "zoom_patch_size": 4}
    assert entry["grounder_spec"] == {"kind": "oracle"}
