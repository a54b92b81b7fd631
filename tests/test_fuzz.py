"""Fuzzing the parsers and readers: random text and random bytes give the project's own errors, never
a traceback from somewhere else; and a walk over every command with bad values of each option."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from abm.cli import build_parser
from abm.cli import main as cli_main
from abm.data.episode_store import EpisodeFormatError, load_episode, read_info
from abm.language.instruction import InstructionError, decompose_instruction
from abm.policy.checkpoint import load_checkpoint
from abm.sim.splits import SplitFileError, load_splits
from conftest import TINY_POLICY

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@FUZZ
@given(st.text(max_size=200))
def test_instruction_parser_never_crashes(text: str) -> None:
    try:
        target, skill = decompose_instruction(text)
    except InstructionError:
        return
    assert isinstance(target, str) and target and isinstance(skill, str) and "X" in skill


@FUZZ
@given(st.sampled_from(["put the ", "pick up the ", "stack the ", "place the "]), st.text(max_size=40),
       st.sampled_from([" in the plate", " on the target", " in the shelf", "", " onto the "]))
def test_instruction_parser_on_near_misses(prefix: str, middle: str, suffix: str) -> None:
    try:
        decompose_instruction(prefix + middle + suffix)
    except InstructionError:
        pass


@FUZZ
@given(st.binary(max_size=4096))
def test_episode_reader_refuses_random_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("ep") / "random.h5"
    path.write_bytes(data)
    with pytest.raises(EpisodeFormatError):
        load_episode(path)
    with pytest.raises(EpisodeFormatError):
        read_info(path)


@FUZZ
@given(st.one_of(st.text(max_size=300),
                 st.builds(lambda body: "version: 1\ntasks:\n" + body, st.text(max_size=200))))
def test_split_reader_refuses_random_text(tmp_path_factory, text: str) -> None:
    path = tmp_path_factory.mktemp("splits") / "splits.yaml"
    path.write_bytes(text.encode("utf-8", errors="replace"))  # hypothesis text may hold lone surrogates
    try:
        load_splits(path)
    except SplitFileError:
        pass


@FUZZ
@given(st.binary(max_size=4096))
def test_checkpoint_reader_refuses_random_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("ck") / "random.pt"
    path.write_bytes(data)
    with pytest.raises(ValueError):
        load_checkpoint(path)


# --------------------------------------------------------------------------------------------------
# The command line: every numeric option of every command is range-checked when parsed, and every
# expected failure is one `abm: error:` line with exit code 2 (never a traceback)
# --------------------------------------------------------------------------------------------------
def _numeric_options(parser, words=()):
    """``(command words, option, action)`` of every option that takes a number, in every sub-command."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _numeric_options(sub, (*words, name))
        elif action.option_strings and getattr(action.type, "__name__", "") in ("int", "float"):
            yield words, action.option_strings[0], action


PARSER = build_parser()
NUMERIC = list(_numeric_options(PARSER))


def _one_error_line(rc, err: str, *needles: str) -> str:
    assert rc == 2, (rc, err)
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("abm: error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], err  # progress lines may come before it
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
    return errors[0]


def test_every_numeric_option_has_a_checked_range() -> None:
    commands = {words[0] for words, _, _ in NUMERIC}
    assert {"train", "eval", "run", "view", "data", "clip", "ground", "render", "quickstart"} <= commands
    unchecked = [(w, o) for w, o, a in NUMERIC if a.type in (int, float)]
    assert unchecked == [], "numeric options without a range (use abm.configuration.int_range / float_range)"


@pytest.mark.parametrize("words, option, action", NUMERIC, ids=[" ".join((*w, o)) for w, o, _ in NUMERIC])
def test_numeric_options_refuse_bad_values_at_parse_time(words, option, action, capsys) -> None:
    bad = ["abc", "1.5", "-5", "1" + "0" * 25] if action.type.__name__ == "int" else ["abc", "nan", "inf", "1e999"]
    for value in bad:
        with pytest.raises(SystemExit) as exit_info:
            PARSER.parse_args([*words, option, *[value] * (action.nargs if isinstance(action.nargs, int) else 1)])
        _one_error_line(exit_info.value.code, capsys.readouterr().err, f"argument {option}", repr(value),
                        f"see abm {' '.join(words)} --help")


@FUZZ
@given(st.sampled_from(NUMERIC), st.one_of(st.text(max_size=12), st.integers(-10**30, 10**30).map(str),
                                           st.floats().map(repr)))
def test_numeric_option_types_give_a_number_or_their_own_error(option, text: str) -> None:
    import argparse
    import math

    _, _, action = option
    try:
        value = action.type(text)
    except argparse.ArgumentTypeError as err:
        assert "expected " in str(err)
        return
    assert isinstance(value, int | float) and math.isfinite(value)
    assert action.type(str(value)) == value  # what parses, parses again to itself


def _bad_inputs(tmp: Path) -> list[tuple[list[str], str]]:
    """``(argv, part of the expected error)`` of failures after parsing, one per kind of bad input."""
    afile = tmp / "a_file"
    afile.write_text("x")
    (tmp / "empty.yaml").write_text("")
    (tmp / "list.yaml").write_text("- arm\n")
    (tmp / "nan.yaml").write_text("limits: {max_step_m: .nan}\n")
    train = ["train", "--method", "abm", "--steps", "1", "--synthetic", "1", "--no-progress"]
    return [
        ([*train, "--out", str(tmp / "r1"), "--set", "unknown=1"], "has no settable field 'unknown'"),
        ([*train, "--out", str(tmp / "r2"), "--set", "resolution=abc"], "--set resolution='abc': expected a whole"),
        ([*train, "--out", str(tmp / "r3"), "--set", "noequals"], "--set expects KEY=VALUE"),
        ([*train, "--out", str(afile / "run")], "a_file"),
        (["train", "--method", "abm", "--steps", "1", "--out", str(tmp / "r4"), "--data", str(tmp / "none")],
         "is not a folder"),
        (["eval", "--run", str(tmp / "none"), "--tasks", "pick_block"], "does not exist"),
        (["export", "--run", str(tmp / "none"), "--out", str(tmp / "x.pt")], "no checkpoint or run folder"),
        (["data", "generate", "--task", "nothing", "--split", "seen", "--episodes", "1", "--out", str(tmp / "d")],
         "unknown task"),
        (["data", "generate", "--task", "pick_block", "--split", "seen", "--episodes", "1", "--out", str(afile)],
         "is a file; give a folder"),
        (["data", "info", str(tmp / "none")], "not a directory"),
        (["run", "--robot", str(tmp / "empty.yaml"), "--run", str(tmp)], "empty.yaml: the robot file is empty"),
        (["run", "--robot", str(tmp / "list.yaml"), "--run", str(tmp)], "list.yaml: expected a mapping"),
        (["run", "--robot", str(tmp / "nan.yaml"), "--run", str(tmp)], "limits.max_step_m: expected a finite"),
        (["run", "--robot", str(tmp / "none.yaml"), "--run", str(tmp)], "is not a file"),
        (["view", "--episode", str(tmp / "none.h5")], "is not a file"),
        (["clip", "train", "--out", str(afile), "--shards", "1"], "a_file"),
        *_bad_experiments(tmp),
    ]


def _bad_experiments(tmp: Path) -> list[tuple[list[str], str]]:
    """Experiment specs a careless or hostile user writes (issue 57): each refused in one line naming the key,
    before any job runs or any file is written."""
    import yaml
    from tests.test_experiments import _one_run

    def spec(name: str, **changes: object) -> list[str]:
        data = _one_run()  # one run that needs no benchmark CLIP
        for dotted, value in changes.items():
            node = data
            *parents, last = dotted.split("__")
            for key in parents:
                node = node[key]
            if value is None:
                node.pop(last)
            else:
                node[last] = value
        (tmp / f"{name}.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
        return ["experiment", "run", str(tmp / f"{name}.yaml"), "--root", str(tmp), "--dry-run"]

    return [
        (spec("episodes", data__episodes=10**30), "data.episodes: expected a whole number from 1 to 1000000"),
        (spec("seed", data__seed=2**70), "data.seed: expected a whole number from 0 to 4294967295"),
        (spec("task", data__tasks=["juggle"]), "data.tasks: 'juggle' is no task of the benchmark"),
        (spec("out", out=""), "out: '' is the root itself"),
        (spec("escape", report__document="../../README.md"), "report.document: '../../README.md' leaves the root"),
        (spec("absolute", kept="/etc"), "kept: '/etc' leaves the root"),
        (spec("patch", training__policy={"resolution": 32, "patch_size": 6}),
         "policy: patch_size 6 must divide the view resolution 32"),
        ([*spec("nocarry", carry=None)[:-1], "--stages", "carry"], "--stages carry: tiny keeps no carry"),
    ]


def _bad_files(tmp: Path, run: Path) -> list[tuple[list[str], str]]:
    """``(argv, the start of the expected message)`` of bad files, each given to the commands that read it: the
    message names the file (or the option) and the fix (issue 38, item 7)."""
    import hashlib
    import json
    import os
    import pickle

    import h5py

    from abm.data.episode_store import save_episode
    from abm.train.synthetic import synthetic_episodes
    from abm.viewer.browser import find_chromium

    tmp.mkdir(parents=True, exist_ok=True)
    recipe_tag, recipe_bad = tmp / "tag.yaml", tmp / "broken.yaml"
    recipe_tag.write_text(f"lr: !!python/object/apply:os.system ['touch {tmp / 'ran'}']\n")
    recipe_bad.write_text("lr: [1, 2\nsteps: 3\n")
    dataset = tmp / "dataset"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta" / "info.json").write_text("[1, 2]")
    zoo = tmp / "zoo"
    zoo.mkdir()
    (zoo / "m.pt").write_bytes(b"m")
    (zoo / "index.json").write_text(json.dumps([{"name": "m", "file": "m.pt", "size_bytes": "big",
                                                 "sha256": hashlib.sha256(b"m").hexdigest()}]))
    data = tmp / "typed"
    save_episode(synthetic_episodes(1, 32)[0], data / "ep.h5")
    episode = data / "ep.h5"
    with h5py.File(episode, "r+") as f:
        f.attrs["seed"] = "abc"
    typed = f"{episode}: attribute 'seed' is 'abc' (text), expected a whole number; the file was damaged or edited"
    (tmp / "empty").mkdir()
    evil = tmp / "evil.pt"
    evil.write_bytes(pickle.dumps(type("Evil", (), {"__reduce__": lambda self: (os.system, ("true",))})(),
                                  protocol=2))
    ckpt = next((run / "checkpoints").glob("step_*.pt"))
    train = ["train", "--method", "abm", "--steps", "1", "--no-progress"]
    cases = [
        (["train", "--config", str(recipe_tag), "--method", "abm", "--synthetic", "1", "--out", str(tmp / "t1")],
         f"{recipe_tag}: not a valid recipe (YAML error at line 1, column 5: the tag !!python/object/apply:os.system "
         "would build a Python object); remove the tag"),
        (["train", "--config", str(recipe_bad), "--method", "abm", "--synthetic", "1", "--out", str(tmp / "t2")],
         f"{recipe_bad}: not a valid recipe (YAML error at line 2, column 6: expected ',' or ']', but got ':'"),
        (["data", "import", "--format", "lerobot", str(dataset), "--out", str(tmp / "imported")],
         str(dataset / "meta" / "info.json")),
        (["zoo", "list", "--zoo", str(zoo)],
         f"{zoo / 'index.json'}: entry 0 (m): 'size_bytes' is 'big', expected a whole number >= 0: fix the entry"),
        (["calibrate", "--recording", str(tmp), "--camera", "front", "--out", str(tmp / "c.yaml"),
          "--board", "5x7:-0.04:0.03:DICT_4X4_50"],
         "argument --board: '5x7:-0.04:0.03:DICT_4X4_50': the square side is in metres and must be > 0"),
        ([*train, "--data", str(data), "--out", str(tmp / "t3")], typed),
        (["ground", "--episode", str(episode), "--out", str(tmp / "g1")], typed),
        (["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(tmp / "e1")], typed),
        ([*train, "--data", str(tmp / "empty"), "--out", str(tmp / "t4")],
         f"no episodes in {tmp / 'empty'} (no *.h5 episode files in it or its folders)"),
        (["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "3", "--batch", "2",
          "--lr", "3e-3", "--warmup", "1", "--out", str(run), "--resume", "--no-progress",
          *[f"--set={k}={v}" for k, v in TINY_POLICY.items() if k != "width"], "--set=width=64"],
         f"{ckpt}: the checkpoint was trained with other policy settings than this model in 1 field(s): width: "
         "checkpoint 32, model 64. Build the model with the checkpoint's values (--set width=32), or train a new run"),
        (["quickstart", "--methods", "foo", "--out", str(tmp / "q")], "argument --methods: invalid choice: 'foo'"),
        (["export", "--run", str(evil), "--out", str(tmp / "x.pt")],
         f"refusing to load {evil}: it holds Python objects other than tensors and plain data (it names the Python "
         "object posix.system), which an abm checkpoint never does (it may be crafted to run code)"),
    ]
    if find_chromium() is not None:  # without --screenshot, a file that loaded would be served until stopped
        cases.append((["view", "--episode", str(episode), "--screenshot", str(tmp / "s.png")], typed))
    return cases


def test_every_command_gives_one_error_line_for_bad_input(tmp_path, capsys, tiny_run) -> None:
    bad_files = _bad_files(tmp_path / "files", tiny_run)
    for argv, needle in [*_bad_inputs(tmp_path), *bad_files]:
        try:
            rc = cli_main(argv)
        except SystemExit as exit_info:
            rc = exit_info.code
        line = _one_error_line(rc, capsys.readouterr().err, needle)
        for unclear in ("weights_only", " ?:", "None", "<unicode string>", "Traceback"):
            assert unclear not in line, (unclear, line)
    assert not (tmp_path / "files" / "ran").exists()


def test_a_write_that_fails_names_its_file(tmp_path, capsys) -> None:
    """A failed write names no file (`cannot use ?: File too large`): the command names the one it wrote."""
    import resource
    import signal

    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (2048, hard))
    try:
        rc = cli_main(["ground", "--out", str(tmp_path / "g")])
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)
    line = _one_error_line(rc, capsys.readouterr().err, f"cannot write {tmp_path / 'g'}/camera_")
    assert line.endswith(".png: File too large; the file size limit of this process was reached (ulimit -f)")


def test_viewer_exits_with_one_line_on_a_busy_port_or_without_chromium(tmp_path, capsys, monkeypatch) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        rc = cli_main(["view", "--episode", str(tmp_path / "ep.h5"), "--port", str(port)])
        _one_error_line(rc, capsys.readouterr().err, f"cannot serve on 127.0.0.1:{port}", "choose another --port")
    rc = cli_main(["view", "--episode", str(tmp_path / "ep.h5"), "--host", "no.such.host.invalid"])
    _one_error_line(rc, capsys.readouterr().err, "cannot serve on no.such.host.invalid")
    monkeypatch.setenv("PATH", str(tmp_path))  # no Chromium on it
    rc = cli_main(["view", "--episode", str(tmp_path / "ep.h5"), "--port", str(port), "--screenshot",
                   str(tmp_path / "s.png")])
    _one_error_line(rc, capsys.readouterr().err, "--screenshot needs Chromium")


def test_python_dash_m_gives_the_same_one_line(tmp_path) -> None:
    """`python -m abm.cli` (as torchrun runs it) reports command errors like the `abm` script."""
    import os
    import subprocess
    import sys

    import abm

    src = str(Path(abm.__file__).parents[1])
    done = subprocess.run([sys.executable, "-m", "abm.cli", "train", "--method", "abm", "--steps", "1", "--synthetic",
                           "1", "--out", str(tmp_path / "r"), "--set", "unknown=1"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": src}, timeout=120)
    _one_error_line(done.returncode, done.stderr, "has no settable field 'unknown'")


_LIMIT_VALUES = st.one_of(st.floats(), st.integers(-10, 10), st.text(max_size=4), st.none(), st.booleans(),
                          st.lists(st.one_of(st.floats(), st.integers(-2, 2), st.text(max_size=2)), max_size=4))


@FUZZ
@given(st.dictionaries(st.sampled_from(["workspace_lower", "workspace_upper", "max_step_m", "max_tilt_deg", "x"]),
                       _LIMIT_VALUES, max_size=5))
def test_robot_limits_either_load_as_real_limits_or_are_refused(tmp_path_factory, limits: dict) -> None:
    import math

    import yaml

    from abm.robot.run import RobotConfig

    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_text(yaml.safe_dump({"limits": limits}))
    try:
        loaded = RobotConfig.load(path).limits
    except ValueError as err:
        assert str(err).startswith(f"{path}: ")
        return
    lower, upper = loaded.workspace_lower, loaded.workspace_upper
    assert all(math.isfinite(v) for v in (*lower, *upper, loaded.max_step_m, loaded.max_tilt_deg))
    assert all(lo < hi for lo, hi in zip(lower, upper, strict=True))
    assert loaded.max_step_m > 0 and 0 < loaded.max_tilt_deg <= 180


@FUZZ
@given(st.text(max_size=300))
def test_robot_file_reader_refuses_random_text(tmp_path_factory, text: str) -> None:
    from abm.robot.run import RobotConfig

    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_bytes(text.encode("utf-8", errors="replace"))
    try:
        RobotConfig.load(path)
    except ValueError:
        pass
