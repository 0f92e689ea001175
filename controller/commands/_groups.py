"""Command groups (``heliocal report ...``, ``heliocal sim ...``): a group is a subpackage of
:mod:`controller.commands`; each public module in it defines ``register(subparsers)`` like a
top-level command module (modules starting with ``_`` are its commands' helpers)."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from types import ModuleType


def command_modules(package: ModuleType) -> list[ModuleType]:
    """Every top-level command module of ``package`` (:mod:`controller.commands`), sorted by name:
    its public modules and groups, and the public modules of its shelves (packages without
    ``register``); helpers (``_``) and the package's ``ENTRY_POINTS`` are not commands."""
    found = []
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_") or info.name in getattr(package, "ENTRY_POINTS", ()):
            continue
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        if info.ispkg and not hasattr(module, "register"):
            found.extend(command_modules(module))  # a shelf: its commands are top-level ones
        else:
            found.append(module)
    return sorted(found, key=lambda m: m.__name__.rsplit(".", 1)[-1])


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
