"""The life of a database file around :class:`controller.storage.db.CampaignStore`'s open: what
is refused before anything is written (another program's database), the schema upgrade (all
steps in one transaction: a failed upgrade changes nothing), and the removal of a file an open
created when the command is refused — so a refusal leaves no new file behind."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

from controller.errors import InputError
from controller.storage.checks import check_schema


def check_foreign(db: sqlite3.Connection, path: Path, readonly: bool) -> None:
    """Refuse a database that another program made (tables but no heliocal schema version),
    and, read-only, an empty one."""
    if int(db.execute("PRAGMA user_version").fetchone()[0]):
        return
    tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
    if tables:
        raise InputError(f"{path}: not a heliocal database (it holds other tables: "
                         f"{', '.join(sorted(tables)[:5])}); nothing was written")
    if readonly:
        raise InputError(f"{path}: empty database, no campaign recorded")


def upgrade(store, migrations: tuple[str, ...]) -> None:
    """Apply the migrations ``store``'s database lacks, all in one transaction (``store.tx()``).
    An older heliocal database must hold its version's schema first; a failed step rolls every
    step back: InputError naming the file, the versions and the reason."""
    path, latest = store.path, len(migrations)
    version = store.schema_version
    if version > latest:
        raise InputError(f"{path}: database schema v{version} is newer than this heliocal understands "
                         f"(v{latest})")
    if version == latest:
        return
    if version:
        check_schema(store._db, path, migrations[:version])
    try:
        with store.tx() as db:
            for v in range(version, latest):
                for stmt in migrations[v].split(";"):
                    if stmt.strip():
                        db.execute(stmt)
            db.execute(f"PRAGMA user_version={latest}")
    except (sqlite3.Error, InputError) as exc:
        why = str(exc).removeprefix(f"{path}: ")
        raise InputError(f"{path}: upgrading the schema from v{version} to v{latest} failed ({why}); "
                         "nothing was changed") from None


def records_nothing(db: sqlite3.Connection) -> bool:
    """Whether every table of ``db`` is empty (a database only just created)."""
    try:
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return not any(db.execute(f'SELECT 1 FROM "{t}" LIMIT 1').fetchone() for t in tables)
    except (sqlite3.Error, InputError):
        return False


def remove_new_database(path: Path, existed: bool) -> None:
    """Remove the database file an open created and SQLite's side files; an empty file that was
    there before is left empty."""
    for suffix in ("-wal", "-shm", "-journal"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    if existed:
        os.truncate(path, 0)
    else:
        path.unlink(missing_ok=True)
