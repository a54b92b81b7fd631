"""Every command's --help: each option says what it does, shows its default, and --no-X flags read as "off"."""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys

import pytest

from abm.cli import build_parser, command_function, main


def all_parsers(parser: argparse.ArgumentParser, name: str = "abm") -> list[tuple[str, argparse.ArgumentParser]]:
    found = [(name, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                found += all_parsers(sub, f"{name} {sub_name}")
    return found


PARSERS = all_parsers(build_parser())
UNSHOWN = (None, False, argparse.SUPPRESS, [], ())


def test_the_walk_finds_every_command() -> None:
    names = {name for name, _ in PARSERS}
    assert {"abm train", "abm eval", "abm data generate", "abm clip train", "abm ground", "abm run",
            "abm view", "abm quickstart", "abm export"} <= names


def test_every_command_names_a_function_that_exists() -> None:
    """Parsers name their command as ``"abm.cli.commands.<group>:<function>"`` (imported when it runs)."""
    named = [(name, parser._defaults["func"]) for name, parser in PARSERS if "func" in parser._defaults]
    assert len(named) > 15
    for name, func in named:
        assert callable(command_function(func)), name
        if isinstance(func, str):
            assert func.startswith("abm.cli.commands."), (name, func)


@pytest.mark.parametrize("name,parser", PARSERS, ids=[n for n, _ in PARSERS])
def test_help_describes_every_option_with_its_default(name: str, parser: argparse.ArgumentParser, capsys,
                                                     monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "10000")  # one line per option, so its help can be found in the output
    with pytest.raises(SystemExit) as exit_:
        main([*name.split()[1:], "--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    problems = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)):
            continue
        flag = action.option_strings[0] if action.option_strings else action.dest
        help_text = " ".join(parser._get_formatter()._get_help_string(action).split())  # as --help prints it
        assert help_text.split(" (default")[0] in text
        if not help_text:
            problems.append(f"{flag}: no help")
            continue
        if action.option_strings and action.default not in UNSHOWN and not isinstance(
                action, (argparse._StoreFalseAction, argparse._StoreTrueAction)) and "default" not in help_text:
            problems.append(f"{flag}: help does not show its default {action.default!r}")
        if isinstance(action, argparse._StoreFalseAction) and flag.startswith("--no-"):
            words = help_text.lower().split()
            if not {"no", "not", "off", "without", "skip", "hide", "never", "don't"} & set(words[:3]):
                problems.append(f"{flag}: help reads as the opposite of the flag: {help_text!r}")
        if flag == "--clip-model" and "random weights, for tests only" not in help_text:
            problems.append(f"{flag}: does not say that 'tiny' / 'random:ARCH' CLIPs are for tests only")
    assert not problems, f"{name}:\n" + "\n".join(problems)
    assert "%(" not in text  # argparse formatting placeholders are filled


def test_abm_help_imports_nothing_heavy() -> None:
    """`abm --help` imports no heavy library (torch, mujoco, transformers, numpy, ...) and no command module: what
    keeps it at ~0.25 s on an idle 2-core machine (timed in docs, not here: wall time depends on the load)."""
    code = ("import sys; from abm.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = [m for m in ('torch', 'mujoco', 'transformers', 'numpy', 'h5py', 'viser') if m in sys.modules]\n"
            "ours = [m for m in sys.modules if m.startswith('abm.')]\n"
            "print(repr((heavy, ours)), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    heavy, ours = ast.literal_eval(done.stderr.strip().splitlines()[-1])
    assert heavy == [], f"abm --help imported {heavy}"
    commands = [m for m in ours if m.startswith("abm.cli.commands.")]
    assert commands == [], f"abm --help imported command modules {commands}"
