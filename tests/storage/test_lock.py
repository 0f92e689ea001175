"""One campaign process per database: the lock, its owner, stale locks, and the CLI refusal."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from controller.storage.db import CampaignStore
from controller.storage.lock import CampaignLock, DatabaseBusy
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[2]

HOLDER = """
import sys, time
from controller.storage.lock import CampaignLock
lock = CampaignLock(sys.argv[1]); lock.acquire("campaign")
print("held", flush=True)
sys.stdin.read()  # hold until the test closes our stdin (or kills us)
"""


@pytest.fixture
def holder(tmp_path):
    """Another process holding the campaign lock of ``tmp_path/c.db``."""
    db = tmp_path / "c.db"
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(db)], cwd=REPO, stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    yield db, p
    if p.poll() is None:
        p.kill()
    p.wait(scaled_s(10))


def test_second_writer_is_refused_naming_the_owner(holder):
    db, p = holder
    lock = CampaignLock(db)
    with pytest.raises(DatabaseBusy, match=rf"pid {p.pid} on .* since"):
        lock.acquire()
    assert lock.owner()["pid"] == p.pid and not lock.held


def test_lock_of_a_killed_process_is_taken_over(holder):
    db, p = holder
    os.kill(p.pid, signal.SIGKILL)
    p.wait(scaled_s(10))
    lock = CampaignLock(db)
    assert lock.owner()["pid"] == p.pid  # its record is still there
    lock.acquire()
    assert lock.held and lock.owner()["pid"] == os.getpid()
    lock.release()


def test_the_lock_file_is_removed_by_the_process_that_made_it_only(tmp_path, holder):
    lock = CampaignLock(tmp_path / "own.db")
    lock.acquire()
    assert lock.path.exists()
    lock.release()
    assert not lock.path.exists()  # made here: removed
    lock.path.write_text("")  # made by someone else (an older heliocal, a dead process)
    lock.acquire()
    lock.release()
    assert lock.path.exists()
    db, p = holder  # a live holder's lock: a refused acquire leaves it
    with pytest.raises(DatabaseBusy):
        CampaignLock(db).acquire()
    assert CampaignLock(db).path.exists() and CampaignLock(db).owner()["pid"] == p.pid


def test_store_takes_the_lock_when_a_campaign_opens(tmp_path):
    args = {"config_path": "c.yaml", "config_sha256": "ab", "light_source": "lamp", "target": "t",
            "queue": ["H1"]}
    with CampaignStore(tmp_path / "c.db") as a, CampaignStore(tmp_path / "c.db") as b:
        a.open_campaign("n1", **args)
        with pytest.raises(DatabaseBusy):
            b.open_campaign("n2", **args)
        assert b.campaign_by_name("n2") is None  # nothing written by the refused one
    with CampaignStore(tmp_path / "c.db") as c:  # released on close
        c.open_campaign("n2", **args)


def test_cli_campaign_on_a_busy_database_exits_2_before_any_work(holder, tmp_path):
    db, p = holder
    r = subprocess.run([sys.executable, "-m", "controller.cli", "campaign", "run", "--config",
                        str(REPO / "configs" / "demo.yaml"), "--db", str(db), "--simulate", "--json"],
                       cwd=REPO, capture_output=True, text=True, timeout=scaled_s(60))
    assert r.returncode == 2, r.stderr
    err = json.loads(r.stdout)["error"]
    assert str(db) in err and f"pid {p.pid}" in err
    assert not (tmp_path / "c-sim").exists()  # no error set rendered, no plant started
    assert not db.exists()  # the refused run created the database and removed it again
    assert (tmp_path / "c.db.lock").exists()  # the holder's lock file is not removed by the refused run


def test_readers_open_read_only_and_refuse_foreign_files(tmp_path):
    from controller.storage.db import open_existing

    foreign = tmp_path / "other.db"
    with sqlite3.connect(foreign) as c:
        c.execute("CREATE TABLE things (x)")
    before = foreign.read_bytes()
    for opener in (open_existing, CampaignStore):
        with pytest.raises(Exception, match="not a heliocal database"):
            opener(foreign)
    assert foreign.read_bytes() == before
    empty = tmp_path / "empty.db"
    empty.write_bytes(b"")
    with pytest.raises(Exception, match="empty database"):
        open_existing(empty)
    assert empty.stat().st_size == 0  # not turned into a database
