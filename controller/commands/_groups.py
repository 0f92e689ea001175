"""Command groups (``heliocal report ...``, ``heliocal sim ...``) whose sub-commands come from
several modules. A group ``G`` discovers modules named ``_G_<name>.py`` in this package; each
defines ``register(subparsers)`` like a top-level command module."""

from __future__ import annotations

import argparse
import importlib
import pkgutil

from controller import commands


def register_group(subparsers, group: str, help_text: str) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(group, help=help_text, description=help_text)
    sub = parser.add_subparsers(dest=f"{group}_command", metavar="SUBCOMMAND")
    prefix = f"_{group}_"
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith(prefix):
            importlib.import_module(f"{commands.__name__}.{info.name}").register(sub)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    return parser
