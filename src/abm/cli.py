"""The ``abm`` command.

Each command group lives next to the code it drives, in a module that exposes
``register(subparsers)``; this file only collects them. Heavy imports (torch, mujoco,
transformers) happen inside the command functions so ``abm --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import typing
from collections.abc import Sequence

import abm

# Modules that add sub-commands, in the order they appear in ``abm --help``.
COMMAND_MODULES: tuple[str, ...] = (
    "abm.render.commands",
    "abm.data.commands",
    "abm.sim.commands",
    "abm.grounding.commands",
    "abm.train.commands",
    "abm.evaluation.commands",
    "abm.robot.commands",
    "abm.viewer.commands",
    "abm.quickstart",
)


class CommandError(Exception):
    """A user-facing error: printed as ``abm: error: ...`` without a traceback."""


class _Parser(argparse.ArgumentParser):
    """Bad options are one ``abm: error:`` line (exit code 2) naming the option, what it expects, and the help."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"abm: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="abm",
        description="Attention before Manipulation: ground the target object, mark it in virtual views, "
        "and predict the next gripper keyframe.",
    )
    parser.add_argument("--version", action="version", version=f"abm {abm.__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def configure_logging(level: int = logging.INFO) -> None:
    """abm's own messages (the ``abm`` logger) to stderr as plain lines; other libraries keep their defaults."""
    logger = logging.getLogger("abm")
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.propagate = False
    for handler in logger.handlers:  # the current stderr, also when main() runs again with stderr redirected
        if type(handler) is logging.StreamHandler and handler.stream is not sys.stderr:
            handler.stream = sys.stderr  # not setStream: it flushes the old stream, which may be closed
    logger.setLevel(level)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging()
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except (CommandError, FileNotFoundError, ValueError, KeyError) as err:
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"abm: error: {message}", file=sys.stderr)
        return 2
    except OSError as err:  # a path or the disk: the user's to fix (other OS errors are bugs: traceback)
        from abm.files import USER_ERRNOS, write_error

        if err.errno not in USER_ERRNOS:
            raise
        print(f"abm: error: {write_error(err.filename or '?', err, verb='use')}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("abm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    # `python -m abm.cli` (and torchrun): run the imported module's main, so the command modules' CommandError
    # (from abm.cli) is the class main catches, not a second copy defined in __main__
    from abm.cli import main as _main

    sys.exit(_main())
