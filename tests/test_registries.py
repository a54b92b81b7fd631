"""One registry per extension point (issue 39, item 4): an unknown name is one error listing the known ones, the
command line's choices are the registries' names, and a grounder, a language-free task, a dataset format and a
camera / arm registered here (as a new module would) are picked up by the parser and the commands without
editing another file. Also: the typed, nested training configuration reads every committed run and checkpoint
(the flat form ``grounder: clip`` + ``grounder_options`` + ``language: null``) as what it meant then.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch
import yaml

from abm.cli import build_parser, main
from abm.configuration import apply_config_file, check_overrides
from abm.data.formats import DATASET_FORMATS, DatasetFormat, register_format
from abm.grounding.config import (
    GROUNDERS,
    ClipGrounderConfig,
    ClipModelConfig,
    GrounderConfig,
    GrounderKind,
    OracleGrounderConfig,
    build_grounder,
    grounder_config_from_dict,
    grounder_from_flags,
    register_grounder,
)
from abm.grounding.mask_field import MaskField
from abm.policy.language_config import (
    LANGUAGES,
    ClipLanguageConfig,
    HashLanguageConfig,
    language_config_from_dict,
)
from abm.policy.variants import VARIANTS, get_variant
from abm.registry import Registry, UnknownNameError, resolve
from abm.robot.kinds import ARM_KINDS, CAMERA_KINDS, Arm, Camera, DeviceKind, register_arm, register_camera
from abm.schema import Field, SchemaError, text
from abm.train.config import TrainConfig, grounding_from_flags
from abm.train.loop import changed_settings

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- the helper
def test_a_registry_is_a_mapping_with_one_way_in_and_one_error() -> None:
    r: Registry[int] = Registry("widget")
    r.register("a", 1)
    assert r.register("b", 2) == 2
    assert r.names() == ("a", "b") == tuple(r) and r["a"] == 1 and "b" in r and len(r) == 2
    assert r.get("c") is None and "c" not in r and ["x"] not in r  # a mapping's get / in, also for a list
    with pytest.raises(UnknownNameError) as err:
        r["c"]
    assert str(err.value) == "unknown widget 'c'; choose from a, b"  # not KeyError's quoted form
    assert isinstance(err.value, KeyError) and isinstance(err.value, ValueError)  # old catchers still catch it
    with pytest.raises(UnknownNameError, match="unknown widget"):
        r[["x"]]  # type: ignore[index]  # an unhashable name read from a file
    with pytest.raises(ValueError, match="registered twice"):
        r.register("a", 3)
    with pytest.raises(ValueError, match="non-empty word"):
        r.register("a b", 3)
    assert r.unregister("b") == 2 and r.names() == ("a",)


def test_names_of_a_subset_and_resolve() -> None:
    @dataclass(frozen=True)
    class Entry:
        cached: bool
        fast: bool = True

    r: Registry[Entry] = Registry("thing")
    r.register("x", Entry(cached=True))
    r.register("y", Entry(cached=False))
    r.register("z", Entry(cached=True, fast=False))
    assert r.names(cached=True) == ("x", "z") and r.names(cached=True, fast=True) == ("x",)
    assert resolve("abm.registry:Registry") is Registry
    assert resolve("abm.grounding.config:GrounderConfig.with_clip") is GrounderConfig.with_clip
    assert resolve(len) is len
    with pytest.raises(ValueError, match="module:attribute"):
        resolve("abm.registry")


def test_the_registries_the_parsers_read_are_light() -> None:
    code = ("import sys\nimport abm.grounding.config, abm.policy.language_config, abm.policy.variants, "
            "abm.data.formats, abm.train.config\n"
            "print([m for m in ('torch', 'numpy', 'mujoco', 'scipy') if m in sys.modules])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


# ------------------------------------------------------------------------------------ unknown names
def _robot_file(tmp_path: Path, cameras: str, arm: str = "{kind: dry-run}") -> Path:
    path = tmp_path / "robot.yaml"
    path.write_text(f"cameras: {cameras}\narm: {arm}\n")
    return path


@pytest.mark.parametrize("name", ["grounder", "language", "variant", "task", "format"])
def test_an_unknown_name_lists_the_known_ones(name: str) -> None:
    from abm.sim.tasks import TASKS, get_task

    lookups = {"grounder": (lambda: grounder_config_from_dict({"kind": "sam"}), GROUNDERS),
               "language": (lambda: language_config_from_dict({"kind": "bert"}), LANGUAGES),
               "variant": (lambda: get_variant("act"), VARIANTS),
               "task": (lambda: get_task("juggle"), TASKS),
               "format": (lambda: DATASET_FORMATS["rlds"], DATASET_FORMATS)}
    lookup, registry = lookups[name]
    with pytest.raises(UnknownNameError) as err:
        lookup()
    assert f"choose from {', '.join(registry.names())}" in str(err.value)


def test_an_unknown_camera_or_arm_kind_lists_the_known_ones(tmp_path: Path) -> None:
    from abm.robot import RobotConfig

    with pytest.raises(SchemaError, match=re.escape(f"cameras.kind: expected one of {list(CAMERA_KINDS)}")):
        RobotConfig.load(_robot_file(tmp_path, "{kind: zed}"))
    with pytest.raises(SchemaError, match=re.escape(f"arm.kind: expected one of {list(ARM_KINDS)}")):
        RobotConfig.load(_robot_file(tmp_path, "{kind: sim}", "{kind: franka}"))


def test_an_unknown_choice_is_refused_when_parsed(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["train", "--method", "abm", "--out", "x", "--steps", "1", "--grounder", "sam"])
    assert "argument --grounder: invalid choice: 'sam' (choose from 'oracle', 'clip')" in capsys.readouterr().err
    with pytest.raises(ValueError, match="expected one of oracle, clip, got 'tracking'"):
        check_overrides(TrainConfig, {"grounder": "tracking"}, option="")  # an experiment spec's override


# ------------------------------------------------------------------------------------ CLI choices
def _parsers(parser: argparse.ArgumentParser, name: str = "abm") -> Iterator[tuple[str, argparse.ArgumentParser]]:
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def _choices(parser: argparse.ArgumentParser) -> dict[tuple[str, str], tuple[str, ...] | None]:
    return {(name, a.dest): tuple(a.choices) if a.choices is not None else None
            for name, p in _parsers(parser) for a in p._actions}


def expected_choices() -> dict[tuple[str, str], tuple[str, ...]]:
    """Every option of the command line that names an extension point, and the registry names it offers."""
    return {
        ("abm train", "grounder"): GROUNDERS.names(per_frame=True),
        ("abm train", "language"): LANGUAGES.names(),
        ("abm train", "method"): VARIANTS.names(),
        ("abm quickstart", "methods"): VARIANTS.names(),
        ("abm eval", "grounder"): GROUNDERS.names(),
        ("abm run", "grounder"): GROUNDERS.names(),
        ("abm view", "grounder"): GROUNDERS.names(per_frame=True),
        ("abm ground", "grounder"): GROUNDERS.names(per_frame=True),
        ("abm data ground", "grounder"): GROUNDERS.names(cached=True),
        ("abm data export", "format"): DATASET_FORMATS.names(),
        ("abm data import", "format"): DATASET_FORMATS.names(),
    }


def test_every_choice_list_of_an_extension_point_is_its_registrys() -> None:
    found = _choices(build_parser())
    for key, names in expected_choices().items():
        assert found[key] == names, key
    # no other option offers grounders, language encoders, variants or formats from a list of its own
    named = {"grounder", "language", "method", "methods", "format"}
    assert {k for k, v in found.items() if k[1] in named and v is not None} == set(expected_choices())


# ------------------------------------------------------------------------------------ a new grounder
@dataclass(frozen=True)
class EverythingGrounderConfig(GrounderConfig):
    """A grounder a test adds: every point is the target (``margin`` only to have an option)."""

    kind: ClassVar[str] = "everything"

    margin: float = 0.0
    _given: frozenset[str] = field(default=frozenset(), compare=False, repr=False)


class EverythingGrounder:
    name = "everything"

    @classmethod
    def from_config(cls, config: EverythingGrounderConfig, **runtime: Any) -> EverythingGrounder:
        return cls()

    def ground(self, observation: Any, cloud: Any, target: str, object_names: Any = None) -> MaskField:
        ones = np.ones(len(cloud), np.float32)
        return MaskField(ones, ones.copy(), True, target, "", confidence=1.0)


@pytest.fixture
def everything() -> Iterator[None]:
    register_grounder(GrounderKind(EverythingGrounderConfig, f"{__name__}:EverythingGrounder.from_config",
                                   "every point", cached=True))
    try:
        yield
    finally:
        GROUNDERS.unregister("everything")


def test_a_registered_grounder_is_offered_trained_and_saved(everything, tmp_path: Path, tiny_policy) -> None:
    from abm.policy import KeyframePolicy, PolicyConfig
    from abm.policy.language import HashLanguageEncoder

    found = _choices(build_parser())  # a parser built now offers it wherever its attributes fit
    for key in (("abm train", "grounder"), ("abm eval", "grounder"), ("abm run", "grounder"),
                ("abm ground", "grounder"), ("abm view", "grounder"), ("abm data ground", "grounder")):
        assert "everything" in found[key], key
    args = build_parser().parse_args(["train", "--method", "abm", "--out", str(tmp_path), "--steps", "1",
                                      "--grounder", "everything"])
    grounder, language = grounding_from_flags(args.grounder, args.language)
    assert grounder == EverythingGrounderConfig() and language is None
    with pytest.raises(ValueError, match="--clip-model/--clip-device need --grounder clip or --language clip"):
        grounding_from_flags("everything", None, "tiny")
    cfg = TrainConfig(grounder={"kind": "everything", "margin": 0.5})
    assert cfg.to_dict()["grounder"] == {"kind": "everything", "margin": 0.5}
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg and cfg.language_config == HashLanguageConfig()
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['colour'\] for the 'everything' grounder"):
        grounder_config_from_dict({"kind": "everything", "colour": "red"})
    assert isinstance(build_grounder({"kind": "everything"}), EverythingGrounder)
    config = PolicyConfig.from_preset("small", "abm", **tiny_policy)
    policy = KeyframePolicy(config, HashLanguageEncoder(config.lang_dim), EverythingGrounderConfig(margin=0.5))
    assert isinstance(policy.grounder, EverythingGrounder)
    assert policy.grounder_spec == {"kind": "everything", "margin": 0.5}  # what a checkpoint stores


# ------------------------------------------------------------------------------------ a new task
@pytest.fixture
def still_task() -> Iterator[type]:
    from abm.sim.tasks import TASKS
    from abm.sim.tasks.base import Task, register_task

    @register_task
    class HoldStill(Task):  # a task module's class: name, instructions, categories, success, expert
        name = "hold_still_test"
        templates = ("put the {target} on the target", "hold the {target} still")
        categories = ("block",)
        seed_salt = 97
        skills = ({"skill": "hold X still", "patterns": ["(hold|keep) {X} still"],
                   "examples": ["hold the red block still"]},)  # a wording the built-in templates lack

        def success(self, sim: Any, instance: Any) -> bool:
            return True

        def expert(self, sim: Any, instance: Any) -> Iterator[Any]:
            yield from ()

    try:
        yield HoldStill
    finally:
        TASKS.unregister("hold_still_test")


def test_a_registered_task_is_known_without_naming_it_elsewhere(still_task, capsys) -> None:
    from abm.data.generate import expand_tasks, trainable_tasks
    from abm.language.instruction import TemplateParser, load_templates
    from abm.language.resolve import task_categories

    assert expand_tasks("hold_still_test") == ["hold_still_test"] and "hold_still_test" in trainable_tasks()
    assert main(["tasks", "--task", "hold_still_test"]) == 0
    out = capsys.readouterr().out
    assert "hold_still_test  [trainable]" in out and "template: put the X on the target" in out
    # its skills (a built-in one, and its own) and the categories the instruction resolver lets it act on come
    # from its class
    templates = load_templates()
    skills = {s.skill: s.tasks for s in templates.skills}
    assert "hold_still_test" in skills["put X on the target"] and skills["hold X still"] == ("hold_still_test",)
    parsed = TemplateParser(templates).parse("please keep the blue block still")
    assert (parsed.target, parsed.skill, parsed.tasks) == ("blue block", "hold X still", ("hold_still_test",))
    assert task_categories("hold_still_test") == ("block",)


# ------------------------------------------------------------------------------------ a new dataset format
@dataclass
class NotesReport:
    episodes: int

    def summary(self, out: Any) -> str:
        return f"{self.episodes} episode notes -> {out}"


def export_notes(data: Path, out: Path, **options: Any) -> NotesReport:
    Path(out).mkdir(parents=True)
    (Path(out) / "notes.json").write_text(json.dumps({"data": str(data), **options}))
    return NotesReport(0)


def import_notes(dataset: Path, out: Path, overwrite: bool = False, task: str | None = None,
                 split: str | None = None) -> list[Path]:
    return []


@pytest.fixture
def notes_format() -> Iterator[None]:
    register_format("notes", DatasetFormat(f"{__name__}:export_notes", f"{__name__}:import_notes", "test notes",
                                           export_options=("frames",)))
    try:
        yield
    finally:
        DATASET_FORMATS.unregister("notes")


def test_a_registered_format_is_offered_written_and_read(notes_format, tmp_path: Path, capsys, cli_errors) -> None:
    assert "notes" in _choices(build_parser())[("abm data export", "format")]
    out = tmp_path / "ds"
    assert main(["data", "export", "--format", "notes", "--data", str(tmp_path), "--out", str(out), "--frames",
                 "keyframes"]) == 0
    assert f"0 episode notes -> {out}" in capsys.readouterr().out
    assert json.loads((out / "notes.json").read_text())["frames"] == "keyframes"  # the options it takes
    assert main(["data", "export", "--format", "notes", "--data", str(tmp_path), "--out", str(tmp_path / "b"),
                 "--crf", "20"]) == 2
    assert cli_errors() == ["abm: error: --crf: not an option of --format notes (it takes --frames)"]
    assert main(["data", "import", str(out), "--format", "notes", "--out", str(tmp_path / "episodes")]) == 0
    assert f"0 episodes -> {tmp_path / 'episodes'}" in capsys.readouterr().out


# ------------------------------------------------------------------------------------ a new camera and arm
class StillCamera:
    """A camera a test adds: one black 8x8 frame."""

    def __init__(self, options: Mapping[str, Any]) -> None:
        self.side = int(options.get("side", 8))

    def read(self) -> dict[str, Any]:
        from abm.types import CameraFrame

        k = np.array([[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]])
        return {"still": CameraFrame(rgb=np.zeros((self.side, self.side, 3), np.uint8),
                                     depth=np.ones((self.side, self.side), np.float32), intrinsics=k,
                                     extrinsics=np.eye(4))}


class LoggingArm:
    """An arm a test adds: it remembers how it was built."""

    def __init__(self, options: Mapping[str, Any], limits: Any = None, read_only: bool = False) -> None:
        self.read_only, self.limits = read_only, limits

    def state(self) -> tuple[np.ndarray, float]:
        return np.eye(4), 1.0

    def move(self, action: Any) -> str:
        return "logged"


@pytest.fixture
def still_robot() -> Iterator[None]:
    register_camera("still", DeviceKind({"side": Field(text())}, f"{__name__}:StillCamera", "one black frame"))
    register_arm("logging", DeviceKind({}, f"{__name__}:LoggingArm", "remembers"))
    try:
        yield
    finally:
        CAMERA_KINDS.unregister("still")
        ARM_KINDS.unregister("logging")


def test_a_registered_camera_and_arm_are_built_from_a_robot_file(still_robot, tmp_path: Path) -> None:
    from abm.robot import DryRunArm, RobotConfig

    config = RobotConfig.load(_robot_file(tmp_path, "{kind: still, side: '4'}", "{kind: logging}"))
    camera, arm = config.build()
    assert isinstance(camera, StillCamera) and isinstance(camera, Camera) and camera.side == 4
    assert isinstance(arm, LoggingArm) and isinstance(arm, Arm) and arm.limits is config.limits
    _, dry = config.build(dry_run=True)  # a dry run reads the configured arm's start pose, read only
    assert isinstance(dry, DryRunArm) and dry.state()[1] == 1.0
    with pytest.raises(SchemaError, match=r"cameras: unknown keys \['width'\]"):
        RobotConfig.load(_robot_file(tmp_path, "{kind: still, width: 3}"))


# ------------------------------------------------------------------------------------ the typed configuration
def test_training_flags_make_the_typed_grounder_and_language() -> None:
    assert grounding_from_flags("clip", None, "m") == (ClipGrounderConfig(model="m"), None)
    grounder, language = grounding_from_flags("oracle", "clip", "m", "cpu")
    assert grounder == OracleGrounderConfig() and language == ClipLanguageConfig(ClipModelConfig("m", "cpu"))
    assert language.to_dict() == {"kind": "clip", "model": "m", "device": "cpu"}  # the checkpoint's spec
    for flags in (("oracle", None, "m"), ("oracle", "hash", "m")):
        with pytest.raises(ValueError, match="--clip-model/--clip-device need --grounder clip or --language clip"):
            grounding_from_flags(*flags)
    assert grounder_from_flags("tracking", "m").to_dict() == {"kind": "tracking", "inner": {"kind": "clip",
                                                                                            "model": "m"}}
    cfg = TrainConfig(grounder=ClipGrounderConfig(model="m", threshold=0.4))
    assert cfg.language is None and cfg.language_config == ClipLanguageConfig(ClipModelConfig("m"))  # the grounder's
    assert cfg.language_config.clip_model() == cfg.grounder.clip_model()  # one CLIP model, shared
    assert cfg.to_recipe()["grounder"] == "clip" and cfg.to_recipe()["clip_model"] == "m"


def test_the_flat_and_the_nested_form_read_the_same() -> None:
    flat = {"grounder": "clip", "grounder_options": {"model": "tiny", "mode": "field", "threshold": 0.3},
            "language": None, "out": "runs/x", "data": None, "removed_option": 1}
    cfg = TrainConfig.from_dict(flat)
    assert cfg.grounder == ClipGrounderConfig(model="tiny", mode="field", threshold=0.3) and cfg.language is None
    assert cfg.out == Path("runs/x") and cfg.data is None
    nested = cfg.to_dict()
    assert nested["grounder"] == {"kind": "clip", "model": "tiny", "mode": "field", "threshold": 0.3}
    assert "grounder_options" not in nested and TrainConfig.from_dict(nested) == cfg
    assert changed_settings({**flat, "seed": 0}, cfg) == {}
    # rvt_clip's form: the oracle with the CLIP's options, read by the clip language encoder
    rvt = TrainConfig.from_dict({"grounder": "oracle", "grounder_options": {"model": "m"}, "language": "clip"})
    assert rvt.grounder == OracleGrounderConfig() and rvt.language == ClipLanguageConfig(ClipModelConfig("m"))
    other = TrainConfig.from_dict({**flat, "grounder_options": {**flat["grounder_options"], "threshold": 0.5}})
    assert set(changed_settings(flat, other)) == {"grounder"}  # the text tokens depend on the CLIP model alone
    another = TrainConfig.from_dict({**flat, "grounder_options": {**flat["grounder_options"], "model": "other"}})
    assert set(changed_settings(flat, another)) == {"grounder", "language"}  # the language follows the grounder's CLIP


def _committed_runs() -> list[tuple[str, dict[str, Any], dict[str, Any] | None, dict[str, Any] | None]]:
    """``(name, saved train options, saved language spec, saved grounder spec)`` of every committed run folder
    and checkpoint (models/, the carry of unfinished trainings, tests/data)."""
    found = []
    for config in sorted([*ROOT.glob("models/**/config.json"), *ROOT.glob("tests/data/**/config.json")]):
        data = json.loads(config.read_text())
        if "train" in data:
            found.append((str(config.relative_to(ROOT)), data["train"], data["language"], data["grounder"]))
    for path in sorted([*ROOT.glob("models/**/*.pt"), *ROOT.glob("tests/data/**/*.pt")]):
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        if ckpt.get("train_config"):
            found.append((str(path.relative_to(ROOT)), ckpt["train_config"], ckpt.get("language"),
                          ckpt.get("grounder")))
    return found


COMMITTED = _committed_runs()


def test_the_committed_runs_are_found() -> None:
    names = [name for name, *_ in COMMITTED]
    assert any(n.startswith("models/") and n.endswith(".pt") for n in names)
    assert any("checkpoints_v1" in n for n in names)
    assert any(isinstance(train["grounder"], str) for _, train, _, _ in COMMITTED)  # written in the flat form


@pytest.mark.parametrize("name,train,language,grounder", COMMITTED, ids=[c[0] for c in COMMITTED])
def test_every_committed_run_reads_as_what_it_trained(name: str, train: dict[str, Any], language: Any,
                                                      grounder: Any) -> None:
    cfg = TrainConfig.from_dict(train)
    assert changed_settings(train, cfg) == {}  # resuming it with the same options changes nothing
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg and changed_settings(cfg.to_dict(), cfg) == {}
    assert cfg.grounder.to_dict() == grounder  # the grounder the run saved
    assert cfg.language_config.with_width(cfg.policy.lang_dim).to_dict() == language  # the language encoder it built
    assert language_config_from_dict(language).to_dict() == language  # its spec read and written back


def test_every_recipe_reads_as_training_flags(tmp_path: Path) -> None:
    recipes = sorted([*ROOT.glob("src/abm/configs/*.yaml"), *ROOT.glob("models/**/recipe.yaml"),
                      *ROOT.glob("tests/data/**/recipe.yaml")])
    assert len(recipes) >= 4
    for recipe in recipes:
        parser = build_parser()
        argv = ["train", "--config", str(recipe), "--out", str(tmp_path / "run"), "--synthetic", "1", "--method",
                "abm", "--steps", "1"]
        apply_config_file(parser, argv)
        args = parser.parse_args(argv)
        grounder, language = grounding_from_flags(args.grounder or "oracle", args.language, args.clip_model,
                                                  args.clip_device)
        run = recipe.parent / "config.json"
        if run.is_file():  # a run's own recipe gives back its grounder's kind and CLIP (the flags' part of it)
            saved = TrainConfig.from_dict(json.loads(run.read_text())["train"])
            assert (grounder.kind, grounder.clip_options()) == (saved.grounder.kind, saved.grounder.clip_options())
            assert yaml.safe_load(recipe.read_text())["grounder"] == saved.grounder.kind
            assert language == saved.language, recipe


# ------------------------------------------------------------------------------------ the documentation
def test_the_architecture_doc_names_every_registry() -> None:
    doc = (ROOT / "docs" / "architecture.md").read_text()
    section = doc[doc.index("## Registries"):doc.index("## Extending")]
    named = re.findall(r"`(abm(?:\.\w+)+\.[A-Z_]+)`", section)
    named += [f"abm.robot.kinds.{n}" for n in re.findall(r", `([A-Z_]+)` \|", section)]
    registries = {n: resolve(":".join(n.rsplit(".", 1))) for n in named}
    assert all(isinstance(r, Registry) for r in registries.values()), registries
    defined = {m.group(1) for path in (ROOT / "src" / "abm").rglob("*.py")
               for m in re.finditer(r'= Registry\("([^"]+)"\)', path.read_text())}
    assert {"grounder kind", "dataset format", "diagnosis", "report section kind", "job kind"} <= defined
    assert {r.what for r in registries.values()} == defined
    listed = (ROOT / "src" / "abm" / "registry.py").read_text().split('"""')[1]
    assert [n for n in named if f":data:`{n}`" not in listed] == []
