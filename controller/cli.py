"""The ``heliocal`` command line.

Each sub-command lives in its own module in :mod:`controller.commands` (or one of its
shelves, packages by subject: :func:`controller.commands._groups.command_modules`). A module
defines ``register(subparsers)``, which adds its parser and sets ``func`` on it; ``func``
receives the parsed namespace and returns the exit status. Modules are discovered, so adding
a command never touches this file.

Errors derived from :class:`controller.errors.HeliocalError` are printed on one line
(as JSON ``{"ok": false, "error": ...}`` when ``--json`` was given) and end the program with
their exit code; argparse usage errors exit 2 as usual.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading

from controller import __version__, commands
from controller.commands._groups import command_modules
from controller.commands._heap import keep_freed_memory
from controller.commands._numbers import Number
from controller.commands.common import resolve_config
from controller.errors import HeliocalError
from controller.io.json_files import dumps_json


class HeliocalParser(argparse.ArgumentParser):
    """An argument parser whose help reads as plain text: the command modules' docstrings feed
    descriptions, and their reStructuredText marks (``code``, :class:`name`) mean nothing in a
    terminal. Sub-parsers inherit the class (argparse uses the parent's type)."""

    def format_help(self) -> str:
        return plain_text(super().format_help())

    def format_usage(self) -> str:
        return plain_text(super().format_usage())

    json_errors = False  # set by main() when --json was given: usage errors answer in JSON too

    def error(self, message: str):
        """One line, as every other bad input (``--help`` shows the usage): on stderr, or as
        ``{"ok": false, "error": ...}`` on stdout with ``--json``; exit status 2."""
        if HeliocalParser.json_errors:
            print(dumps_json({"ok": False, "error": message}))
        else:
            print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def plain_text(text: str) -> str:
    """Strip reStructuredText roles and inline-literal marks."""
    text = re.sub(r":(?:class|func|mod|meth|data|attr):`~?([^`]+)`", r"\1", text)
    return text.replace("``", "")


def build_parser() -> argparse.ArgumentParser:
    parser = HeliocalParser(
        prog="heliocal",
        description="Heliostat calibration controller for CSP plants.",
    )
    parser.add_argument("--version", action="version", version=f"heliocal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in command_modules(commands):
        module.register(sub)
    _state_ranges(parser)
    return parser


def _state_ranges(parser: argparse.ArgumentParser) -> None:
    """Append each numeric option's range to its help (the range its type checks)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _state_ranges(sub)
        elif isinstance(action.type, Number) and action.help != argparse.SUPPRESS:
            action.help = f"{action.help or ''} [range {action.type.range_text()}]".strip()


def _terminate(signum, frame) -> None:
    # SIGTERM (a scheduler, systemd) takes the same safe path as Ctrl-C: heliostats in motion
    # are parked or stopped, and the outcome is recorded.
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    if threading.current_thread() is not threading.main_thread():
        return _main(argv)  # signal handlers belong to the main thread
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        return _main(argv)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    json_mode = "--json" in (sys.argv[1:] if argv is None else argv)
    HeliocalParser.json_errors = json_mode
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        if exc.code:  # a usage error, already printed: its status, as every other error returns
            return int(exc.code)
        raise  # --help, --version
    finally:
        HeliocalParser.json_errors = False
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    keep_freed_memory()
    resolve_config(args)
    try:
        return int(args.func(args) or 0)
    except HeliocalError as exc:
        if getattr(args, "json", False):
            out = {"ok": False, "error": str(exc)}
            if exc.outcome is not None:
                out["outcome"] = exc.outcome
            print(dumps_json(out))
        else:
            print(f"heliocal {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"heliocal {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``| head``): nothing more to say, and no traceback at exit when
        # Python flushes stdout into the closed pipe.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
