"""The audit trail (``audit`` table): who did what, when — every action that moved hardware,
switched a lamp, started or stopped a night or a campaign, acknowledged or shelved an alarm,
changed a model or an account (docs/plant-integration.md, "Audit").

Rows are only ever added. ``heliocal audit`` and the console's Audit page read them.
"""

from __future__ import annotations

import sqlite3
from datetime import datetime

from controller.alarms.states import now_utc
from controller.errors import InputError
from controller.storage.db import CampaignStore


def insert_audit(db: sqlite3.Connection, user: str, action: str, target: str = "", detail: str = "") -> None:
    """One audit row inside the caller's transaction (with the change it records)."""
    db.execute("INSERT INTO audit (time_utc, user, action, target, detail) VALUES (?,?,?,?,?)",
               (now_utc().isoformat(timespec="milliseconds"), user, action, target or "", detail or ""))


class AuditTrail:
    """The audit trail of ``store`` recording as ``user`` (the orchestration's ``AuditSink``)."""

    def __init__(self, store: CampaignStore, user: str) -> None:
        self.store = store
        self.user = user

    def record(self, action: str, target: str = "", detail: str = "") -> None:
        with self.store.tx() as db:
            insert_audit(db, self.user, action, target, detail)

    def as_user(self, user: str) -> AuditTrail:
        return AuditTrail(self.store, user)


def parse_since(text: str | None) -> datetime | None:
    """``--since``: ISO 8601 with its offset (a date alone is its UTC midnight); InputError otherwise."""
    if text is None:
        return None
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"--since: {text!r} is not an ISO 8601 time "
                         "(e.g. 2026-06-21T18:00:00+00:00)") from None
    if t.tzinfo is None:
        if len(text.strip()) > 10:
            raise InputError(f"--since: {text!r} has no UTC offset; add one (e.g. {text.strip()}Z)")
        t = t.replace(tzinfo=now_utc().tzinfo)
    return t


def audit_entries(store: CampaignStore, since: datetime | None = None, after_id: int = 0,
                  limit: int | None = None) -> list[dict]:
    """Audit rows, oldest first: ``{"time", "user", "action", "target", "detail"}`` (plus
    ``id``), from ``since`` on and after row ``after_id``; the last ``limit`` when given."""
    sql, args = "SELECT * FROM audit WHERE id > ?", [after_id]
    if since is not None:
        sql += " AND julianday(time_utc) >= julianday(?)"
        args.append(since.isoformat())
    if limit is not None:
        sql = f"SELECT * FROM ({sql} ORDER BY id DESC LIMIT ?)"
        args.append(int(limit))
    rows = store.query(sql + " ORDER BY id", tuple(args))
    return [{"id": r["id"], "time": r["time_utc"], "user": r["user"], "action": r["action"],
             "target": r["target"], "detail": r["detail"]} for r in rows]
