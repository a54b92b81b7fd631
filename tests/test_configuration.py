"""Config dataclasses generate their command-line flags (abm.configuration)."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from abm.cli.quickstart import QuickstartConfig
from abm.configuration import add_config_arguments, attribute_docs, config_from_args
from abm.evaluation.runner import EvalSettings
from abm.policy.config import PolicyConfig
from abm.train.config import TrainConfig


@dataclass
class Example:
    """An example config.

    Attributes:
        name: the name, in ``code``.
        count / size: two fields
            sharing one entry.
        tags: labels.
        verbose: talk more.
        fast: go fast.
        path: where.
        hidden: filled by the command.
    """

    name: str = field(default="x", metadata={"choices": ["x", "y"]})
    count: int = field(default=1, metadata={"required": True})
    size: float | None = None
    tags: list[str] = field(default_factory=lambda: ["a"])
    verbose: bool = False
    fast: bool = True
    path: Path = field(default=Path("out"), metadata={"flag": "--where"})
    hidden: dict = field(default_factory=dict, metadata={"cli": False})


def _parser(cls=Example) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(exit_on_error=False)
    add_config_arguments(p, cls)
    return p


def test_attribute_docs_read_grouped_and_continued_entries() -> None:
    docs = attribute_docs(Example)
    assert docs["name"] == "the name, in code."
    assert docs["count"] == docs["size"] == "two fields sharing one entry."
    assert set(docs) == {f.name for f in dataclasses.fields(Example)}


def test_flags_round_trip_into_the_dataclass() -> None:
    args = _parser().parse_args(["--count", "3", "--size", "0.5", "--tags", "b", "c", "--verbose", "--no-fast",
                                 "--where", "some/where", "--name", "y"])
    cfg = config_from_args(Example, args, hidden={"k": 1})
    assert cfg == Example(name="y", count=3, size=0.5, tags=["b", "c"], verbose=True, fast=False,
                          path=Path("some/where"), hidden={"k": 1})
    defaults = config_from_args(Example, _parser().parse_args(["--count", "2"]))
    assert defaults == Example(count=2)


def test_required_choices_and_hidden_fields() -> None:
    p = _parser()
    with pytest.raises(SystemExit):
        p.parse_args([])  # --count is required
    with pytest.raises((SystemExit, argparse.ArgumentError)):
        p.parse_args(["--count", "1", "--name", "z"])
    assert "--hidden" not in p.format_help()
    assert "two fields sharing one entry (default: 1)" not in p.format_help()  # required: no default shown


@pytest.mark.parametrize("cls", [TrainConfig, QuickstartConfig, EvalSettings, PolicyConfig])
def test_every_option_is_documented_and_reachable(cls) -> None:
    docs = attribute_docs(cls)
    p = _parser(cls)
    flags = {a.dest: a for a in p._actions}
    for f in dataclasses.fields(cls):
        assert docs.get(f.name), f"{cls.__name__}.{f.name} has no Attributes entry (it would have no --help)"
        assert f.name in flags or not f.metadata.get("cli", True), f.name


def test_abm_train_flags_build_the_train_config(tmp_path) -> None:
    from abm.cli import build_parser

    args = build_parser().parse_args(
        ["train", "--method", "rvt", "--data", str(tmp_path), "--steps", "7", "--out", str(tmp_path / "r"),
         "--no-augment", "--cameras", "front", "top", "--set", "resolution=64", "--clip-model", "tiny",
         "--language", "clip"])
    cfg = config_from_args(TrainConfig, args, policy=dict(args.overrides))
    assert (cfg.method, cfg.steps, cfg.augment, cfg.camera_names) == ("rvt", 7, False, ["front", "top"])
    assert cfg.policy == PolicyConfig.from_preset("small", "rvt", resolution=64)
    assert cfg.policy.preset_changes() == {"resolution": 64} and cfg.splits == ["seen"] and cfg.progress


def test_policy_flags_are_overrides_of_the_preset(tmp_path, monkeypatch) -> None:
    """Only the policy flags given change the preset's policy (the preset supplies the rest)."""
    import abm.cli.commands.train as loop  # the command's `train` (abm.train.loop.train)
    from abm.cli import main

    seen = {}
    monkeypatch.setattr(loop, "train", lambda cfg, episodes=None: seen.setdefault("cfg", cfg) and {
        "steps": 0, "final_loss": {}, "checkpoint": ""})
    assert main(["train", "--method", "abm", "--synthetic", "1", "--steps", "1", "--out", str(tmp_path),
                 "--patch-size", "6", "--view-resolution", "48", "--workspace-center", "0.5", "0", "0.15",
                 "--set", "width=96"]) == 0
    assert seen["cfg"].policy == PolicyConfig.from_preset("small", "abm", patch_size=6, resolution=48, width=96,
                                                          workspace_center=(0.5, 0.0, 0.15))
    assert seen["cfg"].policy.preset == "small+custom"


def test_train_config_file_with_flags_overriding_it(tmp_path, monkeypatch, capsys) -> None:
    """`abm train --config RECIPE`: the file's values (policy ones under `policy:`) are the defaults, flags win,
    the file can supply required options, and the shipped recipes load (the quickstart reads its own)."""
    import abm.cli.commands.train as loop  # the command's `train` (abm.train.loop.train)
    from abm.cli import main
    from abm.cli.quickstart import QuickstartConfig
    from abm.train.config import TrainConfig

    seen = {}
    monkeypatch.setattr(loop, "train", lambda cfg, episodes=None: seen.__setitem__("cfg", cfg) or {
        "steps": 0, "final_loss": {}, "checkpoint": ""})
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text("method: rvt\nsteps: 30\nlr: 0.002\ncheckpoint-every: 7\naugment: false\n"
                      "policy:\n  resolution: 48\n  patch_size: 6\n  workspace_center: [0.5, 0, 0.15]\n")
    assert main(["train", "--config", str(recipe), "--synthetic", "1", "--out", str(tmp_path / "r"), "--lr",
                 "0.005", "--view-resolution", "60"]) == 0
    cfg = seen["cfg"]
    assert (cfg.method, cfg.steps, cfg.lr, cfg.checkpoint_every, cfg.augment) == ("rvt", 30, 0.005, 7, False)
    assert cfg.policy.preset_changes() == {"resolution": 60, "patch_size": 6, "workspace_center": [0.5, 0.0, 0.15]}
    # without --config, the defaults are the measured CPU recipe
    default = TrainConfig()
    assert (default.optimizer, default.lr, default.warmup, default.batch) == ("adamw", 1e-3, 50, 8)
    # a built-in recipe by name; the quickstart trains with the same file
    assert main(["train", "--config", "quickstart", "--method", "abm", "--synthetic", "1",
                 "--out", str(tmp_path / "q")]) == 0
    quick = QuickstartConfig()
    assert (seen["cfg"].steps, seen["cfg"].lr, seen["cfg"].optimizer) == (quick.steps, quick.lr, quick.optimizer)
    assert seen["cfg"].policy.preset_changes() == quick.policy.preset_changes()
    # unknown keys and missing files are usage errors naming the problem
    recipe.write_text("stepz: 3\n")
    with pytest.raises(SystemExit):
        main(["train", "--config", str(recipe), "--method", "abm", "--synthetic", "1", "--steps", "1",
              "--out", str(tmp_path / "x")])
    assert f"recipe {recipe}: unknown keys ['stepz'] (expected: ['accept_changed_config', " in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--config", str(tmp_path / "nope.yaml"), "--synthetic", "1"])
    assert ("built-in recipe: cpu, paper_tables, paper_tables_v2, paper_tables_v3, quickstart, seen_unseen"
            in capsys.readouterr().err)


def test_every_run_writes_the_recipe_that_retrains_it(tmp_path, monkeypatch) -> None:
    """RUN/recipe.yaml, given back to `abm train --config`, yields the same options (only --out differs)."""
    import abm.cli.commands.train as loop  # the command's `train` (abm.train.loop.train)
    from abm.cli import main

    flags = ["train", "--method", "rvt", "--synthetic", "1", "--camera-resolution", "32", "--steps", "1",
             "--batch", "1", "--lr", "0.002", "--no-augment", "--cameras", "front", "wrist", "--set", "resolution=32",
             "--set", "width=32", "--set", "heads=2", "--set", "layers_within=1", "--set", "layers_joint=1",
             "--set", "stem_channels=8", "--set", "lang_dim=16", "--workspace-center", "0.5", "0", "0.2"]
    seen = []
    real_train = loop.train
    monkeypatch.setattr(loop, "train", lambda cfg, episodes=None: seen.append(cfg) or real_train(cfg, episodes))
    assert main([*flags, "--out", str(tmp_path / "a")]) == 0
    recipe = tmp_path / "a" / "recipe.yaml"
    assert "lr: 0.002" in recipe.read_text()
    monkeypatch.setattr(loop, "train", lambda cfg, episodes=None: seen.append(cfg) or {
        "steps": 0, "final_loss": {}, "checkpoint": ""})
    assert main(["train", "--config", str(recipe), "--synthetic", "1", "--out", str(tmp_path / "b")]) == 0
    first, again = seen
    assert dataclasses.replace(again, out=first.out) == first


@pytest.mark.parametrize("text, option, flag_value, expected", [
    ("lr: .inf\n", "lr", "inf", "expected a finite number > 0, got 'inf'"),
    ("lr: .nan\n", "lr", "nan", "expected a finite number > 0, got 'nan'"),
    ("steps: true\n", "steps", "true", "expected a whole number from 1 to 1000000000, got 'true'"),
    ("steps: 0\n", "steps", "0", "expected a whole number from 1 to 1000000000, got '0'"),
    ("batch: 2.5\n", "batch", "2.5", "expected a whole number from 1 to 1000000000, got '2.5'"),
    ("optimizer: sgd\n", "optimizer", None, "expected one of adamw, lamb, got 'sgd'"),
    ("augment: 'no'\n", "augment", None, "expected true or false, got 'no'"),
    ("steps: null\n", "steps", None, "expected a value, got null"),
    ("tasks: []\n", "tasks", None, "expected at least one value, got an empty list"),
    ("policy:\n  workspace_center: [0.5, 0]\n", "policy.workspace_center", None,
     "expected a list of 3 values, got [0.5, 0]"),
    ("policy:\n  dropout: 1.5\n", "policy.dropout", "1.5", "expected a finite number >= 0 and <= 1, got '1.5'"),
    ("policy:\n  resolution: yes\n", "policy.resolution", "true", "expected a whole number from 1 to 1000000000"),
])
def test_recipe_values_pass_the_checks_of_their_flags(tmp_path, monkeypatch, capsys, text, option, flag_value,
                                                       expected) -> None:
    """One schema for flags and recipe files: a value a flag refuses is refused in a recipe, with the same words,
    before anything runs (`lr: .inf` trained NaN to exit 0, `steps: true` trained one step)."""
    import abm.cli.commands.train as loop  # the command's `train` (abm.train.loop.train)
    from abm.cli import build_parser, main

    ran = []
    monkeypatch.setattr(loop, "train", lambda cfg, episodes=None: ran.append(cfg) or {
        "steps": 0, "final_loss": {}, "checkpoint": ""})
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(text)
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--config", str(recipe), "--method", "abm", "--synthetic", "1", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and ran == [] and "Traceback" not in err
    (line,) = err.strip().splitlines()
    assert line.startswith(f"abm: error: recipe {recipe}: {option}: {expected}"), line
    assert "fix the value in the recipe" in line
    if flag_value is not None:  # the flag's own check, word for word
        action = next(a for a in build_parser()._subparsers._group_actions[0].choices["train"]._actions
                      if a.dest == option.replace("policy.", "policy__"))
        with pytest.raises(SystemExit):
            main(["train", action.option_strings[0], flag_value, "--method", "abm", "--synthetic", "1"])
        assert f"argument {action.option_strings[0]}: {expected}" in capsys.readouterr().err
    recipe.write_text("lr: 1e-3\nsteps: 2\npolicy:\n  dropout: 0.5\n")  # YAML reads 1e-3 as text: still a number
    assert main(["train", "--config", str(recipe), "--method", "abm", "--synthetic", "1",
                 "--out", str(tmp_path / "ok")]) == 0
    assert (ran[0].lr, ran[0].steps, ran[0].policy.dropout, ran[0].policy.preset) == (1e-3, 2, 0.5, "small")
