"""What the OPC UA address space shows, read from the record store (the single source every
process — a CLI night, the console, this server — writes): the night and its progress, each
heliostat's state, last measurement, model and predicted daytime error, the alarm list.

Read in a few queries whatever the field's size; the server polls it and writes only the
values that changed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime

from controller.alarms.states import now_utc
from controller.console.views import last_errors
from controller.hfcs.models import model_versions
from controller.storage.alarms import AlarmBook
from controller.storage.db import CampaignStore


@dataclass
class NightView:
    """The latest night: its name, state (running, finished, partial, aborted, interrupted;
    ``idle`` before the first), geometries planned and measured, progress 0…1 and the field's
    predicted daytime RMS (mrad, NaN until known)."""

    name: str = ""
    state: str = "idle"
    planned: int = 0
    measured: int = 0
    progress: float = 0.0
    predicted_mrad: float = float("nan")


@dataclass
class HeliostatView:
    state: str = "uncalibrated"
    last_measurement_utc: str = ""
    last_error_mrad: float = float("nan")
    predicted_mrad: float = float("nan")
    model_version: int = 0
    model_age_days: float = float("nan")
    terms: dict[str, float] = field(default_factory=dict)


@dataclass
class Snapshot:
    night: NightView
    heliostats: dict[str, HeliostatView]
    alarms: list[dict]
    alarm_event_id: int
    model_ids: dict[str, int]


def night_view(store: CampaignStore) -> NightView:
    rows = store.query("SELECT * FROM nights ORDER BY idx DESC LIMIT 1")
    if not rows:
        return NightView()
    n = rows[0]
    name = n["name"]
    if n["kind"] == "planned":
        planned = store.query("SELECT COUNT(*) FROM plan WHERE night=?", (name,))[0][0]
        prefix = name + "/"  # a planned night's passes are its campaigns "<night>/<pass>"
        measured = store.query(
            "SELECT COUNT(*) FROM heliostat_runs r JOIN campaigns c ON r.campaign_id=c.id "
            "WHERE substr(c.name, 1, ?) = ? AND c.name != ? AND r.status='measured'",
            (len(prefix), prefix, prefix + "calibration"))[0][0]
    else:
        camp = store.query("SELECT id, queue_json FROM campaigns WHERE name=?", (name,))
        planned = len(json.loads(camp[0]["queue_json"])) if camp else 0
        measured = store.query("SELECT COUNT(*) FROM heliostat_runs WHERE campaign_id=?",
                               (camp[0]["id"],))[0][0] if camp else 0
    try:
        predicted = float(json.loads(n["summary_json"]).get("daytime_error_predicted_mrad", {}).get("rms"))
    except (TypeError, ValueError, AttributeError):
        predicted = float("nan")
    return NightView(name, n["status"], int(planned), int(measured),
                     min(1.0, measured / planned) if planned else 0.0, predicted)


def heliostat_views(store: CampaignStore, ids: list[str], now: datetime) -> dict[str, HeliostatView]:
    out = {hid: HeliostatView() for hid in ids}
    for r in store.query("SELECT heliostat_id, status, finished_utc FROM heliostat_runs WHERE id IN "
                         "(SELECT MAX(id) FROM heliostat_runs GROUP BY heliostat_id)"):
        if r["heliostat_id"] in out:
            v = out[r["heliostat_id"]]
            v.state, v.last_measurement_utc = r["status"], r["finished_utc"]
    for hid, err in last_errors(store).items():
        if hid in out and err is not None:
            out[hid].last_error_mrad = float(err)
    for r in store.query("SELECT heliostat_id, predicted_rms_mrad FROM night_heliostats WHERE rowid IN "
                         "(SELECT MAX(rowid) FROM night_heliostats WHERE predicted_rms_mrad IS NOT NULL "
                         "GROUP BY heliostat_id)"):
        if r["heliostat_id"] in out:
            out[r["heliostat_id"]].predicted_mrad = float(r["predicted_rms_mrad"])
    for m in model_versions(store, ids):
        v = out[m["heliostat"]]
        v.model_version, v.terms = m["version"], {k: float(x) for k, x in m["terms"].items()}
        v.model_age_days = (now - datetime.fromisoformat(m["created_utc"])).total_seconds() / 86400.0
    return out


def snapshot(store: CampaignStore, ids: list[str]) -> Snapshot:
    now = now_utc()
    book = AlarmBook(store)
    models = {r["heliostat_id"]: int(r["id"]) for r in store.query(
        "SELECT heliostat_id, MAX(id) AS id FROM model_params GROUP BY heliostat_id")}
    alarms = [a.to_json(now) for a in book.alarms()]
    return Snapshot(night_view(store), heliostat_views(store, ids, now), alarms, book.last_event_id(), models)
