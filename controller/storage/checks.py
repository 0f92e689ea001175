"""Records are validated on their way out of the database (issue 27).

A database may have been edited, truncated or damaged since heliocal wrote it. What comes out
of it is checked here, so a bad record ends in one :class:`RecordError` line naming the
database, the table and, where there is one, the row id (exit 2) — never a traceback:

* :class:`CheckedConnection`: every SQLite failure but a constraint violation (a missing table or
  column, a corrupted page: ``database disk image is malformed``) names the database and the table;
* :func:`check_pages`: the file's pages are sound (readers, at open);
* :func:`check_schema`: every table and column this heliocal's schema has is present (so a
  dropped column is found at open, not as a ``KeyError`` deep in a report);
* :func:`json_column`, :func:`enum_column`: a JSON column that does not parse or holds the
  wrong kind of value, a status or kind this heliocal does not know.
"""

from __future__ import annotations

import functools
import json
import re
import sqlite3
from functools import cache
from pathlib import Path
from typing import Any

from controller.errors import InputError

_TABLE = re.compile(r"\b(?:FROM|INTO|UPDATE|JOIN|TABLE)\s+(\w+)", re.IGNORECASE)


class RecordError(InputError):
    """A record that cannot be read as heliocal wrote it. Exit status 2."""


def _refusal(path: object, sql: str, exc: sqlite3.Error) -> RecordError:
    m = _TABLE.search(sql)
    table = f"table {m.group(1)}: " if m else ""
    return RecordError(f"{path}: {table}{exc}")


class CheckedCursor(sqlite3.Cursor):
    """A cursor whose SQLite failures (but constraint violations, which the store's callers
    rely on) become :class:`RecordError` naming the database and the table."""

    _sql = ""

    def execute(self, sql, parameters=()):
        self._sql = sql
        try:
            return super().execute(sql, parameters)
        except sqlite3.IntegrityError:
            raise
        except sqlite3.Error as exc:
            raise _refusal(self.connection.path, sql, exc) from None

    def fetchone(self):
        try:
            return super().fetchone()
        except sqlite3.Error as exc:  # a damaged page shows when its row is stepped to
            raise _refusal(self.connection.path, self._sql, exc) from None

    def fetchall(self):
        try:
            return super().fetchall()
        except sqlite3.Error as exc:
            raise _refusal(self.connection.path, self._sql, exc) from None


class CheckedConnection(sqlite3.Connection):
    """``sqlite3.connect(..., factory=CheckedConnection)``; set ``path`` after connecting."""

    path: object = "<database>"

    def cursor(self, factory=CheckedCursor):
        return super().cursor(factory)

    def execute(self, sql, parameters=()):
        return self.cursor().execute(sql, parameters)


@cache
def expected_schema(migrations: tuple[str, ...]) -> dict[str, frozenset[str]]:
    """Table → column names after every migration, from an empty in-memory database."""
    db = sqlite3.connect(":memory:")
    try:
        for script in migrations:
            db.executescript(script)
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return {t: frozenset(r[1] for r in db.execute(f"PRAGMA table_info({t})")) for t in tables}
    finally:
        db.close()


def check_schema(db: sqlite3.Connection, path: object, migrations: tuple[str, ...]) -> None:
    """Refuse a database missing a table or a column of this heliocal's schema."""
    for table, columns in sorted(expected_schema(migrations).items()):
        have = {r[1] for r in db.execute(f"PRAGMA table_info({table})").fetchall()}
        if not have:
            raise RecordError(f"{path}: table {table}: missing (the database is damaged or was edited)")
        missing = sorted(columns - have)
        if missing:
            raise RecordError(f"{path}: table {table}: column {missing[0]} missing "
                              "(the database is damaged or was edited)")


def check_pages(db: sqlite3.Connection, path: object) -> None:
    """``PRAGMA quick_check`` (every page's structure, not the indexes' contents): a damaged
    page is refused at open, whichever table it belongs to and whether or not the command
    would have read it. About 1 ms per MB."""
    problems = [r[0] for r in db.execute("PRAGMA quick_check(1)").fetchall()]
    if problems != ["ok"]:
        raise RecordError(f"{path}: damaged ({problems[0].splitlines()[-1][:120]}); "
                          "restore it from a backup")


def json_column(path: object, table: str, row: sqlite3.Row, column: str, kind: type,
                default: Any = None) -> Any:
    """The JSON value of ``row[column]``, which must be a ``kind`` (list or dict); ``default``
    for NULL when given."""
    text = row[column]
    if text is None and default is not None:
        return default
    try:
        value = json.loads(text)
    except (TypeError, ValueError):
        raise RecordError(f"{path}: table {table}, row {row['id']}: {column} is not JSON "
                          f"({str(text)[:40]!r})") from None
    if not isinstance(value, kind):
        raise RecordError(f"{path}: table {table}, row {row['id']}: {column} must hold a JSON "
                          f"{'list' if kind is list else 'object'}, not {type(value).__name__}")
    return value


def enum_column(path: object, table: str, row: sqlite3.Row, column: str, allowed: tuple[str, ...]) -> str:
    """``row[column]``, which must be one of ``allowed``."""
    value = row[column]
    if value not in allowed:
        raise RecordError(f"{path}: table {table}, row {row['id']}: {column} {value!r} is not one of "
                          f"{', '.join(allowed)}")
    return value


def stored_image_path(db_path: Path, image: str | Path) -> str:
    """How an image path is stored: relative to the database's folder when the image lies under
    it, else absolute — so reports find it from any working directory."""
    p = Path(image).resolve()
    base = _folder(str(Path(db_path).absolute()))
    try:
        return p.relative_to(base).as_posix()
    except ValueError:
        return str(p)


@functools.lru_cache(maxsize=16)
def _folder(db_path: str) -> Path:
    """The folder of the database at absolute path ``db_path``, resolved (symbolic links) once
    per database: asked for with every image stored."""
    return Path(db_path).resolve().parent


def resolved_image_path(db_path: Path, stored: str) -> str:
    """The image file of a stored path: absolute as is; relative to the database's folder; for a
    row written before paths were stored so (relative to the folder the command ran in), the
    longest tail of it that exists under the database's folder; else the path as stored."""
    p = Path(stored)
    if p.is_absolute():
        return stored
    base = Path(db_path).parent
    for k in range(len(p.parts)):
        candidate = base.joinpath(*p.parts[k:])
        if candidate.is_file():
            return str(candidate)
    return stored


def has_table(store, table: str) -> bool:
    """Whether ``store``'s database has ``table`` (a read-only store of an older schema may not:
    its readers then have nothing to read, rather than an error)."""
    return bool(store.query("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?", (table,)))
