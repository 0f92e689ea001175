"""Helpers of the plant-integration commands (``alarms``, ``users``, ``audit``, ``opcua``):
the database option that falls back on ``$HELIOCAL_DB``, who a command runs as, and the
password file."""

from __future__ import annotations

import argparse
import getpass
import os
from pathlib import Path

from controller.errors import InputError
from controller.io.yaml_files import read_text

DB_ENV = "HELIOCAL_DB"


def add_db_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", default=None, metavar="DB",
                        help=f"campaign database (SQLite; default ${DB_ENV})")


def database(args: argparse.Namespace, *, must_exist: bool = True) -> Path:
    """``--db``, else ``$HELIOCAL_DB``; InputError when neither is given or the file is missing."""
    db = args.db or os.environ.get(DB_ENV)
    if not db:
        raise InputError(f"no database: pass --db DB or set ${DB_ENV}")
    p = Path(db)
    if must_exist and not p.is_file():
        raise InputError(f"database not found: {p}")
    return p


def heliostat_ids(text: str | None, cfg=None) -> list[str] | None:
    """The ids of ``--heliostats`` (comma-separated, each once, in order; checked against
    ``cfg`` when given), or None without the option; InputError when it names none."""
    if text is None:
        return None
    from controller.commands._id_lists import split_ids

    return split_ids(text, "--heliostats", None if cfg is None else cfg.heliostat)


def cli_user() -> str:
    """Who a command run from a shell acts as in the audit trail: the operating system's user."""
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return f"uid{os.getuid()}"


def read_password(path: str) -> str:
    """The password in ``path``: its one line, without the line ending (a bounded read);
    InputError naming the file when it holds more than one line."""
    text = read_text(path, "password file", max_bytes=4096)
    lines = text.splitlines()
    if len(lines) > 1:
        raise InputError(f"{path}: a password file holds one line (the password), this one {len(lines)}")
    return lines[0] if lines else ""
