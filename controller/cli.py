"""The ``heliocal`` command line.

Each sub-command lives in its own module in :mod:`controller.commands`. A module there
defines ``register(subparsers)``, which adds its parser and sets ``func`` on it; ``func``
receives the parsed namespace and returns the exit status. Modules are discovered, so adding
a command never touches this file.

Errors derived from :class:`controller.errors.HeliocalError` are printed on one line
(as JSON ``{"ok": false, "error": ...}`` when ``--json`` was given) and end the program with
their exit code; argparse usage errors exit 2 as usual.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import re
import signal
import sys
import threading

from controller import __version__, commands
from controller.commands._common import resolve_config
from controller.errors import HeliocalError


class HeliocalParser(argparse.ArgumentParser):
    """An argument parser whose help reads as plain text: the command modules' docstrings feed
    descriptions, and their reStructuredText marks (``code``, :class:`name`) mean nothing in a
    terminal. Sub-parsers inherit the class (argparse uses the parent's type)."""

    def format_help(self) -> str:
        return plain_text(super().format_help())

    def format_usage(self) -> str:
        return plain_text(super().format_usage())


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
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


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
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    resolve_config(args)
    try:
        return int(args.func(args) or 0)
    except HeliocalError as exc:
        if getattr(args, "json", False):
            out = {"ok": False, "error": str(exc)}
            if exc.outcome is not None:
                out["outcome"] = exc.outcome
            print(json.dumps(out))
        else:
            print(f"heliocal {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"heliocal {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
