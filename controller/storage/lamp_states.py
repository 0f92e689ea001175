"""The ``lamp_states`` table: every lamp channel as each night or campaign left it
(docs/lamps.md, "Lights out").

One row per channel per end (:func:`controller.calibration.campaign.lights_out.lights_out_at_end`):
the session (night or campaign name), how it ended, the channel, its ``state`` — ``dark``
(confirmed by the panel), ``lit`` (still confirmed lit after it was switched off),
``no_answer`` (the panel could not tell), ``operator`` (no panel: the operator was asked) —
what the panel was last told (``commanded``), why it is not dark (``detail``) and when.
An alarm list reads the rows not dark after the last one it has seen
(:func:`lamps_not_dark`); the morning report reads :func:`lamp_states`. A database older than
the table has none (read-only readers get nothing).
"""

from __future__ import annotations

from controller.calibration.campaign.field import LampEnd
from controller.calibration.records import utc_now
from controller.storage.checks import has_table
from controller.storage.db import CampaignStore

NOT_DARK = ("lit", "no_answer")


def record_lamp_states(store: CampaignStore, session: str, ended: str, lamps: list[LampEnd]) -> None:
    """Record how ``session`` (ended ``ended``) left each lamp, in one transaction."""
    now = utc_now()
    with store.tx() as db:
        db.executemany("INSERT INTO lamp_states (session, ended, channel, state, commanded, detail, "
                       "checked_utc) VALUES (?,?,?,?,?,?,?)",
                       [(session, ended, e.channel, e.state,
                         None if e.commanded is None else int(e.commanded), e.detail, now) for e in lamps])


def lamp_states(store: CampaignStore, session: str | None = None) -> list[dict]:
    """The recorded end states, oldest first (of ``session`` only when given)."""
    if not has_table(store, "lamp_states"):
        return []
    sql, args = "SELECT * FROM lamp_states", ()
    if session is not None:
        sql, args = sql + " WHERE session=?", (session,)
    return [_row(r) for r in store.query(sql + " ORDER BY id", args)]


def lamps_not_dark(store: CampaignStore, after_id: int = 0) -> list[dict]:
    """Every end state not confirmed dark (``lit``, ``no_answer``) recorded after row
    ``after_id``, oldest first: what an alarm list raises (each dict has its row ``id``)."""
    if not has_table(store, "lamp_states"):
        return []
    rows = store.query("SELECT * FROM lamp_states WHERE state IN (?, ?) AND id>? ORDER BY id",
                       (*NOT_DARK, after_id))
    return [_row(r) for r in rows]


def _row(r) -> dict:
    return {"id": r["id"], "session": r["session"], "ended": r["ended"], "channel": r["channel"],
            "state": r["state"], "commanded": None if r["commanded"] is None else bool(r["commanded"]),
            "detail": r["detail"], "checked_utc": r["checked_utc"]}
