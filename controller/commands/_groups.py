"""Command groups (``heliocal report ...``, ``heliocal sim ...``): a group is a subpackage of
:mod:`controller.commands`; each public module in it defines ``register(subparsers)`` like a
top-level command module (modules starting with ``_`` are its commands' helpers)."""

from __future__ import annotations

import argparse
import importlib
import pkgutil


def register_group(subparsers, package: str, help_text: str,
                   name: str | None = None) -> argparse.ArgumentParser:
    """Add the group ``name`` (default: the last part of ``package``) with every module inside it."""
    group = name or package.rsplit(".", 1)[-1]
    parser = subparsers.add_parser(group, help=help_text, description=help_text)
    sub = parser.add_subparsers(dest=f"{group}_command", metavar="SUBCOMMAND")
    path = importlib.import_module(package).__path__
    for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name):
        if info.name.startswith("_"):  # a private helper of the group's commands
            continue
        importlib.import_module(f"{package}.{info.name}").register(sub)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    return parser
