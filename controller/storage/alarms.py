"""The alarm list and its history in SQLite (``alarms``, ``alarm_events``): the interface
layer's :class:`controller.alarms.sink.AlarmSink` (docs/plant-integration.md, "Alarms").

One row per condition and source holds the alarm's ISA-18.2 state
(:mod:`controller.alarms.states`); every change is one transaction that updates it and appends
its event (raised, cleared, acknowledged, shelved, unshelved) to the history, which is never
rewritten. An acknowledgement or a shelve is audited in the same transaction. Other processes
(the console, the OPC UA server) follow the history by its event ids (:meth:`AlarmBook.events`).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from datetime import datetime, timedelta

from controller.alarms import states
from controller.alarms.conditions import CONDITIONS
from controller.alarms.states import Alarm, now_utc
from controller.errors import InputError
from controller.storage.audit import insert_audit
from controller.storage.checks import RecordError
from controller.storage.db import CampaignStore

_COLUMNS = ("condition", "source", "message", "active", "acked", "raised_utc", "count", "cleared_utc",
            "acked_utc", "acked_by", "ack_comment", "shelved_until_utc", "shelved_by")


def _alarm(path, row: sqlite3.Row) -> Alarm:
    if row["condition"] not in CONDITIONS:
        raise RecordError(f"{path}: table alarms: row {row['id']}: unknown condition {row['condition']!r}")
    return Alarm(row["condition"], row["source"], row["message"], bool(row["active"]), bool(row["acked"]),
                 row["raised_utc"], row["count"], row["cleared_utc"], row["acked_utc"], row["acked_by"],
                 row["ack_comment"], row["shelved_until_utc"], row["shelved_by"], row["id"])


class AlarmBook:
    """The alarms of ``store``. ``clock``: now, as an aware UTC datetime (tests pass their own)."""

    def __init__(self, store: CampaignStore, clock: Callable[[], datetime] = now_utc) -> None:
        self.store = store
        self.clock = clock

    # -- what orchestration raises -------------------------------------------------------------
    def raise_alarm(self, condition: str, source: str, message: str) -> None:
        now = self.clock()
        with self.store.tx() as db:
            row = db.execute("SELECT * FROM alarms WHERE condition=? AND source=?",
                             (condition, source)).fetchone()
            new = states.raised(None if row is None else _alarm(self.store.path, row), condition, source,
                                message, now)
            if new is not None:
                self._write(db, new, "raised", None, message, now)

    def clear_alarm(self, condition: str, source: str | None = None) -> None:
        now = self.clock()
        with self.store.tx() as db:
            sql, args = "SELECT * FROM alarms WHERE condition=? AND active=1", [condition]
            if source is not None:
                sql, args = sql + " AND source=?", [condition, source]
            for row in db.execute(sql, args).fetchall():
                new = states.cleared(_alarm(self.store.path, row), now)
                if new is not None:
                    self._write(db, new, "cleared", None, f"{condition} {new.source} returned to normal", now)

    # -- what operators do ---------------------------------------------------------------------
    def acknowledge(self, alarm_id: int, user: str, comment: str = "") -> Alarm:
        """Acknowledge alarm ``alarm_id`` as ``user`` (audited); InputError when there is no such
        alarm or nothing to acknowledge."""
        return self._operate(alarm_id, user, "acknowledged", "alarm.acknowledge", comment,
                             lambda a, now: states.acknowledged(a, user, comment, now))

    def shelve(self, alarm_id: int, user: str, duration: timedelta, comment: str = "") -> Alarm:
        """Shelve alarm ``alarm_id`` for ``duration`` as ``user`` (audited)."""
        return self._operate(alarm_id, user, "shelved", "alarm.shelve", comment or f"for {duration}",
                             lambda a, now: states.shelved(a, user, duration, now))

    def unshelve(self, alarm_id: int, user: str) -> Alarm:
        return self._operate(alarm_id, user, "unshelved", "alarm.unshelve", "",
                             lambda a, now: states.unshelved(a, now))

    def _operate(self, alarm_id: int, user: str, kind: str, action: str, comment: str, change) -> Alarm:
        now = self.clock()
        with self.store.tx() as db:
            row = db.execute("SELECT * FROM alarms WHERE id=?", (int(alarm_id),)).fetchone()
            if row is None:
                raise InputError(f"{self.store.path}: no alarm {alarm_id} (see heliocal alarms list)")
            new = change(_alarm(self.store.path, row), now)
            text = f"{new.condition} {new.source}" + (f": {comment}" if comment else "")
            self._write(db, new, kind, user, text, now)
            insert_audit(db, user, action, f"alarm {alarm_id}", text)
        return new

    def _write(self, db: sqlite3.Connection, a: Alarm, kind: str, user: str | None, message: str,
               now: datetime) -> None:
        values = (a.condition, a.source, a.message, int(a.active), int(a.acked), a.raised_utc, a.count,
                  a.cleared_utc, a.acked_utc, a.acked_by, a.ack_comment, a.shelved_until_utc, a.shelved_by)
        if a.id is None:
            cur = db.execute(f"INSERT INTO alarms ({', '.join(_COLUMNS)}) "
                             f"VALUES ({', '.join('?' * len(_COLUMNS))})", values)
            alarm_id = cur.lastrowid
        else:
            db.execute(f"UPDATE alarms SET {', '.join(c + '=?' for c in _COLUMNS)} WHERE id=?",
                       (*values, a.id))
            alarm_id = a.id
        db.execute("INSERT INTO alarm_events (alarm_id, time_utc, kind, user, message) VALUES (?,?,?,?,?)",
                   (alarm_id, now.isoformat(timespec="milliseconds"), kind, user, message))

    # -- reading ---------------------------------------------------------------------------------
    def alarm(self, alarm_id: int) -> Alarm:
        rows = self.store.query("SELECT * FROM alarms WHERE id=?", (int(alarm_id),))
        if not rows:
            raise InputError(f"{self.store.path}: no alarm {alarm_id} (see heliocal alarms list)")
        return _alarm(self.store.path, rows[0])

    def alarms(self, *, include_normal: bool = False) -> list[Alarm]:
        """The alarm list, most urgent first (priority, then newest): every alarm not in the
        normal state (shelved ones included), or all with ``include_normal``."""
        now = self.clock()
        out = [_alarm(self.store.path, r) for r in self.store.query("SELECT * FROM alarms ORDER BY id")]
        if not include_normal:
            out = [a for a in out if a.state(now) != "normal"]
        rank = {"high": 0, "medium": 1, "low": 2}
        return sorted(out, key=lambda a: (rank[a.priority], -(a.id or 0)))

    def events(self, after_id: int = 0, alarm_id: int | None = None) -> list[dict]:
        """The history after event ``after_id``, oldest first (of one alarm when given)."""
        sql, args = "SELECT * FROM alarm_events WHERE id > ?", [after_id]
        if alarm_id is not None:
            sql, args = sql + " AND alarm_id=?", [after_id, alarm_id]
        rows = self.store.query(sql + " ORDER BY id", tuple(args))
        return [{"id": r["id"], "alarm_id": r["alarm_id"], "time_utc": r["time_utc"], "kind": r["kind"],
                 "user": r["user"], "message": r["message"]} for r in rows]

    def last_event_id(self) -> int:
        return int(self.store.query("SELECT COALESCE(MAX(id), 0) FROM alarm_events")[0][0])
