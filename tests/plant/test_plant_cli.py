"""``heliocal users``, ``alarms`` and ``audit`` as scripts call them (their contracts), in
this process: accounts with scrypt hashes, acknowledging and shelving with who, the audit
trail as JSON, and bad input refused in one line with exit 2."""

from __future__ import annotations

import json

import pytest

from controller.storage.alarms import AlarmBook
from controller.storage.db import CampaignStore
from controller.storage.users import Accounts, verify_password
from tests.conftest import run_cli


@pytest.fixture
def db(tmp_path, monkeypatch):
    path = tmp_path / "c.db"
    CampaignStore(path).close()
    (tmp_path / "pw").write_text("correct horse\n")
    (tmp_path / "short").write_text("short\n")
    monkeypatch.chdir(tmp_path)
    return path


def test_accounts_are_added_listed_and_removed_with_hashed_passwords(db):
    code, out, err = run_cli(["users", "add", "alice", "--role", "operator", "--password-file", "pw",
                              "--db", str(db)])
    assert code == 0, err
    code, out, _ = run_cli(["users", "list", "--db", str(db), "--json"])
    assert code == 0 and [(u["name"], u["role"]) for u in json.loads(out)] == [("alice", "operator")]
    with CampaignStore(db) as store:
        stored = store.query("SELECT password_hash FROM users WHERE name='alice'")[0][0]
        assert stored.startswith("scrypt$16384$8$1$") and "correct horse" not in stored
        assert verify_password(stored, "correct horse") and not verify_password(stored, "correct horsE")
        assert Accounts(store).check("alice", "correct horse").role == "operator"
        assert Accounts(store).check("alice", "wrong") is None
        assert Accounts(store).check("nobody", "x") is None
    add = ["users", "add"]
    for argv, words in [([*add, "alice", "--role", "viewer", "--password-file", "pw"], "exists"),
                        ([*add, "bob", "--role", "viewer", "--password-file", "short"], "8 to 1024"),
                        ([*add, "bo b", "--role", "viewer", "--password-file", "pw"], "user name"),
                        ([*add, "bob", "--role", "admin", "--password-file", "pw"], "invalid choice"),
                        (["users", "remove", "bob"], "no user 'bob'")]:
        code, out, err = run_cli([*argv, "--db", str(db)])
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, (argv, err)
    assert run_cli(["users", "remove", "alice", "--db", str(db)])[0] == 0
    assert json.loads(run_cli(["users", "list", "--db", str(db), "--json"])[1]) == []
    audit = json.loads(run_cli(["audit", "--db", str(db), "--json"])[1])
    actions = [(r["action"], r["target"]) for r in audit]
    assert actions == [("user.add", "alice"), ("user.remove", "alice")]


def test_alarms_are_listed_acknowledged_and_shelved_from_the_command_line(db, monkeypatch):
    with CampaignStore(db) as store:
        book = AlarmBook(store)
        book.raise_alarm("lamp_not_dark", "lamp", "lamp lamp did not confirm dark within 10 s")
        book.raise_alarm("drift_high", "H03", "H03: pointing error 6.1 mrad with its model")
    monkeypatch.setenv("HELIOCAL_DB", str(db))  # the database of scripts that name none
    code, out, err = run_cli(["alarms", "--json"])
    assert code == 0, err
    alarms = json.loads(out)
    assert [(a["condition"], a["priority"], a["state"]) for a in alarms] == \
        [("lamp_not_dark", "high", "unack_active"), ("drift_high", "low", "unack_active")]
    lamp = alarms[0]["id"]
    code, out, err = run_cli(["alarms", "ack", str(lamp), "--comment", "breaker opened", "--json"])
    assert code == 0, err
    acked = json.loads(out)
    assert acked["acknowledged"] and acked["acknowledged_by"] and acked["ack_comment"] == "breaker opened"
    code, out, _ = run_cli(["alarms", "shelve", str(alarms[1]["id"]), "--for", "2h", "--json"])
    assert code == 0 and json.loads(out)["state"] == "shelved" and json.loads(out)["shelved_until_utc"]
    audit = json.loads(run_cli(["audit", "--json"])[1])
    assert [set(r) for r in audit] == [{"time", "user", "action", "target", "detail"}] * 2
    assert [(r["action"], r["user"]) for r in audit] == [("alarm.acknowledge", acked["acknowledged_by"]),
                                                         ("alarm.shelve", acked["acknowledged_by"])]
    assert json.loads(run_cli(["audit", "--since", "2999-01-01", "--json"])[1]) == []
    for argv, words in [(["alarms", "ack", str(lamp)], "already acknowledged"),
                        (["alarms", "ack", "77"], "no alarm 77"),
                        (["alarms", "shelve", str(lamp), "--for", "forever"], "not a duration"),
                        (["alarms", "shelve", str(lamp)], "--for DURATION"),
                        (["audit", "--since", "yesterday"], "not an ISO 8601 time")]:
        code, out, err = run_cli(argv)
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, (argv, err)


def test_a_command_without_a_database_says_how_to_name_one(tmp_path, monkeypatch):
    monkeypatch.delenv("HELIOCAL_DB", raising=False)
    code, _, err = run_cli(["alarms"])
    assert code == 2 and "pass --db DB or set $HELIOCAL_DB" in err
    code, _, err = run_cli(["audit", "--db", str(tmp_path / "none.db")])
    assert code == 2 and "database not found" in err and not (tmp_path / "none.db").exists()
