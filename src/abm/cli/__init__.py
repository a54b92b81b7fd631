"""The ``abm`` command.

Each command group has two modules here: ``abm.cli.<group>`` builds its parsers (``register(subparsers)``;
light: configuration dataclasses and argparse only) and ``abm.cli.commands.<group>`` holds the command
functions, which import the library (torch, mujoco, transformers) at module level. A parser names its command
as ``func="abm.cli.commands.<group>:<function>"``; :func:`main` imports that one module when the command runs,
so ``abm --help`` imports no command module and stays fast. No library module imports this package.

What a command raises: an :class:`abm.errors.AbmError` (the user's to fix) is one ``abm: error: MESSAGE`` line
(exit code 2), like a usage error of the parser and an ``OSError`` that is the user's to fix (a full disk, no
permission: :data:`abm.files.USER_ERRNOS`); Ctrl-C is ``abm: interrupted`` (exit code 130). Any other exception
is a bug: its traceback, then :data:`BUG_HINT` (exit code 1).
"""

from __future__ import annotations

import argparse
import importlib
import io
import logging
import sys
import traceback
import typing
from collections.abc import Callable, Sequence
from pathlib import Path

import abm
from abm.configuration import apply_config_file
from abm.errors import AbmError
from abm.files import USER_ERRNOS, write_error

# Modules that add sub-commands, in the order they appear in ``abm --help``.
COMMAND_MODULES: tuple[str, ...] = (
    "abm.cli.render",
    "abm.cli.data",
    "abm.cli.sim",
    "abm.cli.ground",
    "abm.cli.clip",
    "abm.cli.train",
    "abm.cli.evaluate",
    "abm.cli.robot",
    "abm.cli.viewer",
    "abm.cli.quickstart",
    "abm.cli.zoo",
    "abm.cli.experiment",
)

#: the line after the traceback of an unexpected exception (a bug: not an :class:`~abm.errors.AbmError`)
BUG_HINT = ("abm: internal error: this is a bug in abm, not in what you asked for; please report it to the "
            "maintainers with the command you ran and the traceback above")


class HelpFormatter(argparse.HelpFormatter):
    """Help that shows every option's default (``(default: X)``) unless its text already names it, or it has
    none worth showing (``None``, switches, empty lists)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        switch = isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                     argparse.BooleanOptionalAction, argparse._HelpAction, argparse._VersionAction))
        if switch or not action.option_strings or "default" in text or default is argparse.SUPPRESS or (
                default is None or default is False or default == [] or default == ()):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class Parser(argparse.ArgumentParser):
    """``abm``'s parsers (and their sub-commands'): help with defaults (:class:`HelpFormatter`); a bad option is
    one ``abm: error:`` line (exit code 2) naming the option, what it expects, and the help."""

    def __init__(self, *args: typing.Any, **kwargs: typing.Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        #: checks of options that go together, run once this (sub-)command's arguments are parsed: each returns
        #: the problem (a usage error) or ``None`` (e.g. ``abm.ray_pool.backend_arguments_problem``)
        self.post_parse_checks: list[Callable[[argparse.Namespace], str | None]] = []

    def parse_known_args(self, args: typing.Any = None, namespace: typing.Any = None) -> typing.Any:
        parsed, extras = super().parse_known_args(args, namespace)
        for check in self.post_parse_checks:
            problem = check(parsed)
            if problem:
                self.error(problem)
        return parsed, extras

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"abm: error: {message} (see {self.prog} --help)\n")

    def _get_value(self, action: argparse.Action, arg_string: str) -> typing.Any:
        """An empty path is refused: ``Path('')`` is the current folder, which ``--out ''`` (an unset shell
        variable) never means, and a command would write (or with ``--overwrite`` replace) files there."""
        if isinstance(arg_string, str) and not arg_string.strip() and (action.type is Path or action.dest == "out"):
            raise argparse.ArgumentError(action, "expected a path, got an empty string; give the path (use . to "
                                                 "mean the current folder)")
        return super()._get_value(action, arg_string)  # argparse's (private) conversion


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="abm",
        description="Attention before Manipulation: ground the target object, mark it in virtual views, "
        "and predict the next gripper keyframe.",
    )
    parser.add_argument("--version", action="version", version=f"abm {abm.__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


class _StderrHandler(logging.StreamHandler[typing.TextIO]):
    """Writes to ``sys.stderr`` as it is when a message is logged (so later redirections are honoured)."""

    @property  # logging.StreamHandler's attribute, read from sys each time
    def stream(self) -> typing.TextIO:
        return sys.stderr

    @stream.setter
    def stream(self, value: typing.TextIO) -> None:  # set by StreamHandler.__init__; the property wins
        pass


def configure_logging(level: int = logging.INFO) -> None:
    """abm's own messages (the ``abm`` logger) to stderr as plain lines; other libraries keep their defaults."""
    logger = logging.getLogger("abm")
    if not logger.handlers:
        ours = _StderrHandler()
        ours.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(ours)
        logger.propagate = False
    for handler in logger.handlers:  # the current stderr, also when main() runs again with stderr redirected
        if type(handler) is logging.StreamHandler and handler.stream is not sys.stderr:
            handler.stream = sys.stderr  # not setStream: it flushes the old stream, which may be closed
    logger.setLevel(level)


def command_function(func: str | Callable[[argparse.Namespace], int | None]
                     ) -> Callable[[argparse.Namespace], int | None]:
    """The function a parser's ``func`` default names (``"module:function"``, imported now), or ``func`` itself."""
    if not isinstance(func, str):
        return func
    module, name = func.split(":")
    function: Callable[[argparse.Namespace], int | None] = getattr(importlib.import_module(module), name)
    return function


def file_in_traceback(err: BaseException) -> str | None:
    """The file an ``OSError`` without a file name was about (a failed ``write`` or ``close`` names none): the
    open file closest to where it was raised, found among the local variables of its frames (and of the errors
    it was raised from, e.g. PIL's failed flush inside its failed close); ``None`` if there is none."""
    seen: set[int] = set()
    error: BaseException | None = err
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        frames = []
        tb = error.__traceback__
        while tb is not None:
            frames.append(tb.tb_frame)
            tb = tb.tb_next
        for frame in reversed(frames):  # innermost first
            for value in frame.f_locals.values():
                name = getattr(value, "name", None) if isinstance(value, io.IOBase) else None
                if isinstance(name, str) and name and not name.startswith("<"):
                    return name
        error = error.__context__ or error.__cause__
    return None


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    apply_config_file(parser, argv)  # a command's --config FILE: its values become that command's defaults
    args = parser.parse_args(argv)
    configure_logging()
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(command_function(args.func)(args) or 0)
    except AbmError as err:
        print(f"abm: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # a path or the disk: the user's to fix (other OS errors are bugs: traceback)
        if err.errno not in USER_ERRNOS:
            return _internal_error()
        # a failed write or close names no file: the open file where it failed does
        path = err.filename or file_in_traceback(err) or "a file of the command's output"
        print(f"abm: error: {write_error(path, err, verb='use' if err.filename else 'write')}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("abm: interrupted", file=sys.stderr)
        return 130
    except Exception:
        return _internal_error()


def _internal_error() -> int:
    """Print the exception being handled with its traceback, then :data:`BUG_HINT`; the exit code (1)."""
    traceback.print_exc()
    print(BUG_HINT, file=sys.stderr)
    return 1
