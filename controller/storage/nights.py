"""The ``nights`` table and the night's plan: what :class:`controller.calibration.night.planned.PlannedNight`
and ``heliocal campaign run`` keep of a night besides its campaigns.

A field's calibration campaign is night 0; each planned night is the next index. A night that
did not finish (killed, interrupted, a lamp that did not confirm) is resumed by the next
``heliocal campaign night`` under the same name and index, with the plan stored for it.
"""

from __future__ import annotations

import json

from controller.calibration.campaign.field import LampEnd
from controller.calibration.night.planner import PlanItem
from controller.calibration.records import CAMPAIGN_STATUSES, NIGHT_KINDS, NightRecord, utc_now
from controller.config import PlantConfig
from controller.storage.checks import enum_column, json_column
from controller.storage.db import CampaignStore
from controller.storage.field_prints import record_field
from controller.storage.geometry_flags import flagged, record_failures
from controller.storage.lamp_states import record_lamp_states
from controller.storage.plans import load_plan, record_plan

NIGHTS_SCHEMA = 8  # the schema version that added the nights table
NIGHT_STATUSES = ("running", *CAMPAIGN_STATUSES)
HELIOSTATS_SCHEMA = 9  # the schema version that added night_heliostats


class NightBook:
    """Nights and plans of one :class:`CampaignStore` (the orchestration's ``NightStore``)."""

    def __init__(self, store: CampaignStore) -> None:
        self.store = store

    def open_night(self, name: str, kind: str) -> tuple[NightRecord, bool]:
        """The night ``name`` — ``(record, resumed)``: resumed when it exists (its status set back
        to running unless it finished), else a new one with the next index."""
        if kind not in NIGHT_KINDS:
            raise ValueError(f"night kind must be one of {NIGHT_KINDS}, got {kind!r}")
        with self.store.tx() as db:
            row = db.execute("SELECT * FROM nights WHERE name=?", (name,)).fetchone()
            if row is not None:
                db.execute("UPDATE nights SET status='running', cause=NULL WHERE id=? AND status!='finished'",
                           (row["id"],))
                return self._get(db, row["id"]), True
            idx = db.execute("SELECT COUNT(*) FROM nights").fetchone()[0]
            cur = db.execute("INSERT INTO nights (idx, name, kind, started_utc) VALUES (?,?,?,?)",
                             (idx, name, kind, utc_now()))
            return self._get(db, cur.lastrowid), False

    def finish_night(self, night_id: int, status: str, cause: str | None, summary: dict) -> None:
        with self.store.tx() as db:
            db.execute("UPDATE nights SET status=?, cause=?, finished_utc=?, summary_json=? WHERE id=?",
                       (status, cause, utc_now(), json.dumps(summary), night_id))

    def add_to_summary(self, name: str, extra: dict) -> None:
        """Merge ``extra`` into night ``name``'s summary (e.g. a simulated plant's true daytime
        error, under ``truth``), in one transaction."""
        with self.store.tx() as db:
            row = db.execute("SELECT id, summary_json FROM nights WHERE name=?", (name,)).fetchone()
            summary = {**json_column(self.store.path, "nights", row, "summary_json", dict), **extra}
            db.execute("UPDATE nights SET summary_json=? WHERE id=?", (json.dumps(summary), row["id"]))

    def nights(self) -> list[NightRecord]:
        """Every night, by index (none in a database older than nights, opened read-only)."""
        if self.store.schema_version < NIGHTS_SCHEMA:
            return []
        return [_night(r, self.store.path) for r in self.store.query("SELECT * FROM nights ORDER BY idx")]

    def passes(self) -> set[int]:
        """The ids of the campaigns that are passes of a planned night (``<night>/...``, not its
        first ``/calibration``): they *measure* their heliostats, the others *calibrate* them —
        what each counts everywhere (``campaign list``, the console)."""
        if self.store.schema_version < NIGHTS_SCHEMA:
            return set()
        rows = self.store.query("SELECT c.id FROM campaigns c JOIN nights n ON n.kind='planned' "
                                "AND substr(c.name, 1, length(n.name) + 1) = n.name || '/' "
                                "WHERE c.name NOT LIKE '%/calibration'")
        return {int(r["id"]) for r in rows}

    def unfinished(self, kind: str = "planned") -> NightRecord | None:
        """The latest night of ``kind`` when it did not finish (to be resumed), else None."""
        rows = self.store.query("SELECT * FROM nights ORDER BY idx DESC LIMIT 1")
        if not rows or rows[0]["kind"] != kind or rows[0]["status"] in ("finished", "partial"):
            return None
        return _night(rows[0], self.store.path)

    def next_index(self) -> int:
        return int(self.store.query("SELECT COUNT(*) AS n FROM nights")[0]["n"])

    def index_for(self, name: str) -> int:
        """The index night ``name`` has, or would get if opened now."""
        rows = self.store.query("SELECT idx FROM nights WHERE name=?", (name,))
        return int(rows[0]["idx"]) if rows else self.next_index()

    def base_name(self) -> str | None:
        """The name of night 0 (the field's calibration campaign), which planned nights are named after."""
        rows = self.store.query("SELECT name FROM nights WHERE idx=0")
        return rows[0]["name"] if rows else None

    def last_end_s(self, night: str) -> float | None:
        """The latest plant time (``end_s``) recorded in night ``night``'s campaigns, or None."""
        rows = self.store.query("SELECT MAX(r.end_s) AS t FROM heliostat_runs r JOIN campaigns c "
                                "ON r.campaign_id=c.id WHERE c.name=? OR substr(c.name, 1, ?)=?",
                                (night, len(night) + 1, night + "/"))
        return None if rows[0]["t"] is None else float(rows[0]["t"])

    def measured(self, night: str) -> dict[str, int]:
        """Per heliostat, the geometries night ``night``'s passes measured, over every session
        (an interrupted pass's runs too: they are recorded as they end)."""
        rows = self.store.query("SELECT r.heliostat_id AS h, COUNT(*) AS n FROM heliostat_runs r "
                                "JOIN campaigns c ON r.campaign_id=c.id WHERE substr(c.name, 1, ?)=? "
                                "AND r.status='measured' GROUP BY r.heliostat_id",
                                (len(night) + 1, night + "/"))
        return {r["h"]: int(r["n"]) for r in rows}

    def record_heliostats(self, night_id: int, rows: list[dict]) -> None:
        """What each heliostat of night ``night_id`` ended with (``night_heliostats``, schema v9:
        position, geometries planned and measured, predicted daytime RMS, why none was
        measurable), replacing what a previous session of the night wrote, in one transaction."""
        with self.store.tx() as db:
            db.execute("DELETE FROM night_heliostats WHERE night_id=?", (night_id,))
            db.executemany("INSERT INTO night_heliostats (night_id, heliostat_id, east_m, north_m, planned, "
                           "measured, predicted_rms_mrad, unmeasurable) VALUES (?,?,?,?,?,?,?,?)",
                           [(night_id, r["heliostat"], r["east_m"], r["north_m"], r["planned"], r["measured"],
                             r["predicted_rms_mrad"], r["unmeasurable"]) for r in rows])

    def heliostats(self, night_id: int) -> list[dict]:
        """The rows :meth:`record_heliostats` wrote for the night (none before schema v9)."""
        if self.store.schema_version < HELIOSTATS_SCHEMA:
            return []
        rows = self.store.query("SELECT * FROM night_heliostats WHERE night_id=? ORDER BY heliostat_id",
                                (night_id,))
        return [{"heliostat": r["heliostat_id"], "east_m": r["east_m"], "north_m": r["north_m"],
                 "planned": r["planned"], "measured": r["measured"],
                 "predicted_rms_mrad": r["predicted_rms_mrad"], "unmeasurable": r["unmeasurable"]}
                for r in rows]

    def record_field(self, cfg: PlantConfig, ids: list[str], config_path: str, sha256: str) -> None:
        """What the models of ``ids`` are fitted on from now (``field_prints``,
        :mod:`controller.storage.field_prints`)."""
        record_field(self.store, cfg, ids, config_path, sha256)

    def record_geometry_failures(self, night: str, failures: list[dict]) -> None:
        """Geometries of night ``night`` tried without a measurement
        (:mod:`controller.storage.geometry_flags`)."""
        record_failures(self.store, night, failures)

    def flagged(self, ids: list[str] | None = None) -> list[dict]:
        """The geometries flagged (failed on two nights) of heliostats ``ids`` (None: all)."""
        return flagged(self.store, ids)

    def record_lamp_states(self, session: str, ended: str, lamps: list[LampEnd]) -> None:
        """How ``session`` left each lamp (``lamp_states``, :mod:`controller.storage.lamp_states`)."""
        record_lamp_states(self.store, session, ended, lamps)

    def plan(self, night: str) -> list[PlanItem]:
        return load_plan(self.store, night)

    def record_plan(self, items: list[PlanItem]) -> None:
        record_plan(self.store, items)

    def _get(self, db, night_id: int) -> NightRecord:
        return _night(db.execute("SELECT * FROM nights WHERE id=?", (night_id,)).fetchone(), self.store.path)


def night_of(campaign: str, nights: list[str]) -> str | None:
    """The night a campaign belongs to: the longest night name it is, or starts with followed by
    ``/`` (a calibration night's campaign has the night's name; a planned night's passes are
    ``<night>/<pass>``, and planned night ``<base>/night-k`` is named after night 0 ``<base>``)."""
    mine = [n for n in nights if campaign == n or campaign.startswith(n + "/")]
    return max(mine, key=len, default=None)


def _night(row, path) -> NightRecord:
    """A ``nights`` row as its record; RecordError naming the database, table and row when a
    column was tampered with (an unknown kind or status, a summary that is not JSON)."""
    return NightRecord(int(row["id"]), int(row["idx"]), row["name"],
                       enum_column(path, "nights", row, "kind", NIGHT_KINDS), row["started_utc"],
                       row["finished_utc"],
                       enum_column(path, "nights", row, "status", NIGHT_STATUSES), row["cause"],
                       json_column(path, "nights", row, "summary_json", dict))
