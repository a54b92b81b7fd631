"""The command line's two kinds of failure (:func:`abm.cli.main`): an :class:`abm.errors.AbmError` is the user's to
fix and is one ``abm: error:`` line with exit code 2; any other exception is a bug in abm and keeps its
traceback, followed by :data:`abm.cli.BUG_HINT` (exit code 1). Also: every ``*Error`` of abm is an ``AbmError``,
and the commands do not turn built-in exceptions into user errors without saying why."""

from __future__ import annotations

import ast
import importlib
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import abm
import abm.cli
import abm.errors
from abm.cli import BUG_HINT, main
from abm.errors import AbmError, CheckpointError, ConfigError, DataError, ExternalError, OutputError, RefusedError
from abm.registry import UnknownNameError

ROOT = Path(abm.__file__).parent
ABM_ERRORS = {name for name, value in vars(abm.errors).items() if isinstance(value, type)
              and issubclass(value, AbmError)}


def _raising(monkeypatch: pytest.MonkeyPatch, error: BaseException) -> None:
    """Make every command raise ``error``."""

    def command(args: object) -> int:
        raise error

    monkeypatch.setattr(abm.cli, "command_function", lambda func: command)


USER_ERRORS = [ConfigError("--steps must be at least 1"), DataError("ep.h5: attribute 'seed' is 'abc'"),
               CheckpointError("no checkpoint or run folder at x"), OutputError("--out x is a file; give a folder"),
               RefusedError("refused before moving: no target"), ExternalError("no Chromium found"),
               UnknownNameError("unknown task 'fly'; choose from pick_block")]


@pytest.mark.parametrize("error", USER_ERRORS, ids=lambda e: type(e).__name__)
def test_a_user_error_is_one_line(monkeypatch, capsys, error: AbmError) -> None:
    _raising(monkeypatch, error)
    assert main(["tasks"]) == 2
    assert capsys.readouterr().err == f"abm: error: {error.args[0]}\n"


BUGS = [RuntimeError("the model diverged"), ValueError("images must be (B, 5, 10, 32, 32), got (2, 3)"),
        KeyError("point_mask"), FileNotFoundError(2, "No such file or directory", "/nowhere/meta.json"),
        TypeError("unsupported operand"), AttributeError("'NoneType' object has no attribute 'rgb'"),
        ZeroDivisionError("division by zero"), OSError(5, "Input/output error")]


@pytest.mark.parametrize("error", BUGS, ids=lambda e: type(e).__name__)
def test_an_unexpected_exception_keeps_its_traceback_and_asks_to_report_it(monkeypatch, capsys,
                                                                         error: Exception) -> None:
    _raising(monkeypatch, error)
    assert main(["tasks"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):\n") and "in command\n" in err, err
    assert f"{type(error).__name__}: " in err and "abm: error:" not in err
    assert err.splitlines()[-1] == BUG_HINT and "report" in BUG_HINT and "traceback above" in BUG_HINT


def test_usage_errors_and_interrupts_stay_as_they_were(monkeypatch, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--steps", "many"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.startswith("abm: error: argument --steps: ")
    _raising(monkeypatch, KeyboardInterrupt())
    assert main(["tasks"]) == 130
    assert capsys.readouterr().err == "abm: interrupted\n"


def test_a_real_command_and_the_process_exit_codes(tmp_path) -> None:
    """Through ``python -m abm.cli``: a user error (an unknown task) and a bug (a command that divides by zero)."""
    done = subprocess.run([sys.executable, "-m", "abm.cli", "tasks", "--task", "fly"], capture_output=True,
                          text=True, check=False)
    assert done.returncode == 2 and done.stderr.startswith("abm: error: unknown task 'fly'; choose from ")
    assert len(done.stderr.splitlines()) == 1
    bug = ("import sys, abm.cli\n"
           "abm.cli.command_function = lambda func: (lambda args: 1 / 0)\n"
           "sys.exit(abm.cli.main(['tasks']))\n")
    done = subprocess.run([sys.executable, "-c", bug], capture_output=True, text=True, check=False, cwd=tmp_path)
    assert done.returncode == 1
    assert "Traceback" in done.stderr and "ZeroDivisionError: division by zero" in done.stderr
    assert done.stderr.splitlines()[-1] == BUG_HINT


def test_every_error_class_of_abm_is_an_abm_error() -> None:
    """Every ``*Error`` class abm defines derives from :class:`abm.errors.AbmError` (so the command line prints
    it as one line), through one of the few kinds of :mod:`abm.errors`."""
    kinds = (ConfigError, DataError, OutputError, RefusedError, ExternalError)
    outside, found = [], 0
    for path in sorted(ROOT.rglob("*.py")):
        classes = [n.name for n in ast.parse(path.read_text()).body
                   if isinstance(n, ast.ClassDef) and n.name.endswith("Error") and not n.name.startswith("_")]
        if not classes:
            continue
        module = importlib.import_module(".".join(("abm", *path.relative_to(ROOT).with_suffix("").parts)))
        for name in classes:
            cls = getattr(module, name)
            found += 1
            if cls is not AbmError and not issubclass(cls, kinds):
                outside.append(f"{module.__name__}.{name}")
    assert found >= 20 and not outside, f"errors that are not an AbmError of a kind in abm.errors: {outside}"


def test_the_commands_do_not_turn_builtin_exceptions_into_user_errors() -> None:
    """A command that catches ``ValueError``, ``KeyError``, ``OSError`` (and its subclasses) or ``Exception`` to
    raise an :class:`AbmError` would print a bug as a user error: each such handler says on its line why the
    built-in exception there is the user's to fix (the library raises AbmErrors itself otherwise)."""
    broad = {"ValueError", "KeyError", "LookupError", "OSError", "FileNotFoundError", "Exception", "BaseException",
             "RuntimeError", "TypeError"}
    silent = []
    for path in sorted((ROOT / "cli").rglob("*.py")):
        lines = path.read_text().splitlines()
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ExceptHandler):
                continue
            types = node.type.elts if isinstance(node.type, ast.Tuple) else [node.type]
            names = {t.id if isinstance(t, ast.Name) else getattr(t, "attr", "") for t in types if t is not None}
            raised = [n.exc for statement in node.body for n in ast.walk(statement) if isinstance(n, ast.Raise)]
            called = [e.func if isinstance(e, ast.Call) else e for e in raised if e is not None]
            raises = any(isinstance(f, ast.Name) and f.id in ABM_ERRORS for f in called)
            if (node.type is None or names & broad) and raises and "#" not in lines[node.lineno - 1]:
                silent.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}")
    assert not silent, "handlers that turn a built-in exception into an abm error without a reason:\n" + "\n".join(
        silent)


def test_a_checkpoint_of_unknown_policy_settings_is_a_checkpoint_error(tiny_run, tmp_path, capsys) -> None:
    """A checkpoint whose policy settings this abm cannot read (a newer abm's field) is the user's file problem:
    a :class:`CheckpointError` naming the file, and one line from a command that builds the policy."""
    from abm.policy import KeyframePolicy
    from abm.policy.checkpoint import load_checkpoint, save_checkpoint

    payload = load_checkpoint(tiny_run)
    payload.pop("path")
    payload["policy_config"] = {**payload["policy_config"], "a_newer_field": 1}
    newer = save_checkpoint(tmp_path / "newer.pt", payload)
    with pytest.raises(CheckpointError, match="newer.pt: its policy settings cannot be read .*a_newer_field"):
        KeyframePolicy.from_checkpoint(newer)
    with socket.socket() as probe:  # a free port: the viewer checks it before it loads the policy
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    assert main(["view", "--run", str(newer), "--task", "pick_block", "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("abm: error: ") and "a_newer_field" in err[-1] and "Traceback" not in "".join(err)
