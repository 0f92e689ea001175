"""Tampered databases (issue 27): every JSON column not JSON or of the wrong kind, every status
or kind unknown, every table dropped, every column dropped, damaged pages — each command that
reads the database ends with one line naming the database (and the table and row id where
there is one), exit 2, no traceback, the database unchanged and nothing written. A read-only
database is still read. Image paths are stored relative to the database's folder, so the
report finds the frames from any working directory."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import random
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from controller.cli import main
from controller.storage.checks import expected_schema
from controller.storage.schema import MIGRATIONS
from tests.conftest import run_cli

pytestmark = pytest.mark.xdist_group("tampered-db")

# (table, column, kind of value written) for every JSON column; (table, column) for every enum.
JSON_COLUMNS = [("campaigns", "queue_json", list), ("campaigns", "meta_json", dict),
                ("model_params", "params_json", dict), ("model_params", "sigma_json", dict),
                ("model_params", "detail_json", dict)]
ENUMS = [("campaigns", "status"), ("heliostat_runs", "status"), ("images", "kind")]
# Which command reads which table (and so must refuse its tampered records).
READERS = {"campaigns": ["list", "report", "export"], "model_params": ["aim", "report"],
           "heliostat_runs": ["list", "report"], "images": ["report"]}


@pytest.fixture(scope="module")
def demo_db(tmp_path_factory) -> Path:
    """A demo database: one heliostat, the calibration night and one planned night."""
    out = tmp_path_factory.mktemp("demo")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert main(["demo", "--heliostats", "1", "--nights", "1", "--out", str(out)]) == 0, err.getvalue()
    db = out / "campaign.db"
    _query(db, "PRAGMA wal_checkpoint(TRUNCATE)")
    return db


def _query(db: Path, sql: str) -> list[tuple]:
    """Rows of ``sql`` on ``db``, the connection closed at once: an open one, closed later by
    the garbage collector, would delete the WAL file while a test copies the folder."""
    with contextlib.closing(sqlite3.connect(db)) as c:
        return c.execute(sql).fetchall()


def _commands(db: Path, out: Path) -> dict[str, list[str]]:
    return {"list": ["campaign", "list", "--db", str(db)],
            "aim": ["aim", "--db", str(db), "--heliostat", "H01", "--sun-az", "180", "--sun-el", "45"],
            "report": ["report", "campaign", "--db", str(db), "--out", str(out / "report"),
                       "--campaign", "demo-n1-seed0"],  # the calibration night: images, model
            "export": ["export", "--db", str(db), "--format", "paint", "--out", str(out / "export")]}


def _tampered(demo_db: Path, tmp_path: Path, *sql: str) -> Path:
    folder = tmp_path / "db"
    shutil.copytree(demo_db.parent, folder, ignore=shutil.ignore_patterns("report", "plant", "errorset"))
    db = folder / demo_db.name
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as c:
        c.execute("PRAGMA ignore_check_constraints=1")
        for stmt in sql:
            c.execute(stmt)
        c.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return db


def _expect_refused(db: Path, tmp_path: Path, commands: list[str], *fragments: str) -> int:
    """Run ``commands`` on ``db``: each must exit 2 with one line naming the database and every
    fragment, change nothing and write nothing. Returns how many were refused."""
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    before = hashlib.sha256(db.read_bytes()).hexdigest()
    for name in commands:
        code, stdout, stderr = run_cli(_commands(db, out)[name])
        lines = [ln for ln in stderr.splitlines() if not ln.startswith("heliocal: using configuration")]
        assert "Traceback" not in stderr, stderr
        assert code == 2 and len(lines) == 1, f"{name}: exit {code}\n{stderr}{stdout[:300]}"
        assert str(db) in lines[0] and all(f in lines[0] for f in fragments), f"{name}: {lines[0]}"
        assert not any(out.iterdir()), f"{name} wrote {list(out.iterdir())}"
    assert hashlib.sha256(db.read_bytes()).hexdigest() == before
    return len(commands)


def test_the_untouched_database_is_read_by_every_command(demo_db, tmp_path):
    db = _tampered(demo_db, tmp_path)
    (tmp_path / "out").mkdir()
    for name, argv in _commands(db, tmp_path / "out").items():
        code, _, stderr = run_cli(argv)
        assert code == 0, f"{name}: {stderr}"


@pytest.mark.parametrize("table,column,kind", JSON_COLUMNS)
@pytest.mark.parametrize("value", ["'{not json'", "'[1, 2'", "'\"text\"'", "'42'"])
def test_a_json_column_that_is_not_json_of_its_kind(demo_db, tmp_path, table, column, kind, value):
    db = _tampered(demo_db, tmp_path, f"UPDATE {table} SET {column}={value}")
    row = _query(db, f"SELECT MIN(id) FROM {table}")[0][0]
    _expect_refused(db, tmp_path, READERS[table], f"table {table}, row ", column)
    assert row is not None


@pytest.mark.parametrize("table,column", ENUMS)
def test_an_unknown_status_or_kind(demo_db, tmp_path, table, column):
    db = _tampered(demo_db, tmp_path, f"UPDATE {table} SET {column}='bogus'")
    _expect_refused(db, tmp_path, READERS[table], f"table {table}, row ", "'bogus'")


def test_an_unknown_correction_kind_through_the_store(demo_db, tmp_path):
    """No command lists corrections (the demo's coarse-move count reads them): the store itself."""
    from controller.storage.checks import RecordError
    from controller.storage.db import open_existing

    db = _tampered(demo_db, tmp_path, "UPDATE corrections SET kind='sideways'")
    with open_existing(db) as store:
        run = store.runs(store.find_campaign("demo-n1-seed0").id)[0]
        with pytest.raises(RecordError, match=rf"{db}: table corrections, row \d+: kind 'sideways' is not"):
            store.corrections(run.id)


@pytest.mark.parametrize("table", sorted(expected_schema(MIGRATIONS)))
def test_a_missing_table(demo_db, tmp_path, table):
    db = _tampered(demo_db, tmp_path, f"DROP TABLE {table}")
    _expect_refused(db, tmp_path, ["list", "aim", "export"], f"table {table}: missing")


def _droppable() -> list[tuple[str, str]]:
    """Every column SQLite lets us drop (not a key, not indexed, not in a constraint)."""
    out = []
    for table, columns in sorted(expected_schema(MIGRATIONS).items()):
        for column in sorted(columns):
            db = sqlite3.connect(":memory:")
            for script in MIGRATIONS:
                db.executescript(script)
            try:
                db.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
            except sqlite3.OperationalError:
                continue
            finally:
                db.close()
            out.append((table, column))
    return out


DROPPABLE = _droppable()


def test_most_columns_can_be_dropped_and_so_are_tried():
    assert len(DROPPABLE) >= 40


@pytest.mark.parametrize("table,column", DROPPABLE)
def test_a_missing_column(demo_db, tmp_path, table, column):
    db = _tampered(demo_db, tmp_path, f"ALTER TABLE {table} DROP COLUMN {column}")
    _expect_refused(db, tmp_path, ["list", "aim"], f"table {table}: column {column} missing")


def test_damaged_pages_are_refused_naming_the_database(demo_db, tmp_path):
    """Every page but the first overwritten in turn with random bytes: every reader refuses the
    file at open (PRAGMA quick_check), whichever table the page belongs to."""
    clean = _tampered(demo_db, tmp_path)
    size = clean.stat().st_size
    page = _query(clean, "PRAGMA page_size")[0][0]
    rng = random.Random(27)
    assert size // page >= 10
    for number in range(1, size // page):
        folder = tmp_path / f"p{number}"
        shutil.copytree(clean.parent, folder)
        db = folder / clean.name
        with open(db, "r+b") as f:
            f.seek(number * page)
            f.write(rng.randbytes(page))
        _expect_refused(db, tmp_path / f"p{number}", ["list", "aim", "export"], "damaged")


def test_a_read_only_database_is_read(demo_db, tmp_path):
    """As a user without write access to the file or its folder (no -shm can be created)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to run a command as an unprivileged user")
    nobody = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable]
    probe = subprocess.run([*nobody, "-c", "import controller.cli"], capture_output=True, text=True,
                           timeout=60, cwd="/")
    if probe.returncode != 0:  # e.g. a checkout inside a 0700 folder such as mktemp -d makes
        pytest.skip("the unprivileged user cannot run this checkout's Python "
                    f"({(probe.stderr.strip().splitlines() or ['?'])[-1]}); clone it where others may read")
    top = Path(tempfile.mkdtemp(prefix="heliocal-ro-"))  # outside pytest's private (0700) folders
    db = _tampered(demo_db, top)
    for p in (top, *top.rglob("*")):
        os.chmod(p, 0o755 if p.is_dir() else 0o644)
    os.chmod(db.parent, 0o555)
    try:
        r = subprocess.run([*nobody, "-m", "controller.cli", "campaign", "list", "--db", str(db)],
                           capture_output=True, text=True, timeout=60, cwd="/")
        assert r.returncode == 0, r.stderr
        assert "demo-n1-seed0" in r.stdout
    finally:
        os.chmod(db.parent, 0o755)
        shutil.rmtree(top)


def test_reports_find_the_frames_from_any_folder(demo_db, tmp_path, monkeypatch):
    paths = [r[0] for r in _query(demo_db, "SELECT path FROM images")]
    assert paths and all(p.startswith("images/") for p in paths), paths[:3]  # relative to the database
    db = _tampered(demo_db, tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    code, _, err = run_cli(["report", "campaign", "--db", os.path.relpath(db), "--out", "r",
                         "--campaign", "demo-n1-seed0"])
    assert code == 0, err
    assert "H01-it1-high.png" in (elsewhere / "r" / "report.md").read_text()
