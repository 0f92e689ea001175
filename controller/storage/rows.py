"""Records from database rows, checked on the way out (:mod:`controller.storage.checks`): the
JSON columns must parse to the kind of value written, the statuses must be known ones."""

from __future__ import annotations

import json
import math
import sqlite3
from pathlib import Path

from controller.calibration.records import (
    CAMPAIGN_STATUSES,
    RUN_STATUSES,
    CampaignRecord,
    MeasurementRecord,
    ModelRecord,
    RunRecord,
    utc_now,
)
from controller.storage.checks import RecordError, enum_column, json_column


def campaign_from_row(row: sqlite3.Row, path: Path) -> CampaignRecord:
    return CampaignRecord(int(row["id"]), row["name"], row["config_path"], row["config_sha256"],
                          row["light_source"], row["target"],
                          json_column(path, "campaigns", row, "queue_json", list),
                          row["started_utc"], row["finished_utc"],
                          enum_column(path, "campaigns", row, "status", ("running", *CAMPAIGN_STATUSES)),
                          json_column(path, "campaigns", row, "meta_json", dict, {}), row["cause"])


def run_from_row(row: sqlite3.Row, path: Path) -> RunRecord:
    return RunRecord(
        row["heliostat_id"], row["queue_index"],
        enum_column(path, "heliostat_runs", row, "status", RUN_STATUSES),
        row["final_state"], row["iterations"],
        row["start_s"], row["end_s"], error_before_mrad=row["error_before_mrad"],
        error_after_mrad=row["error_after_mrad"], matched_label=row["matched_label"],
        fault_cause=row["fault_cause"], fault_state=row["fault_state"], at_standby_s=row["at_standby_s"],
        on_target_s=row["on_target_s"], off_target_s=row["off_target_s"], id=int(row["id"]),
        finished_utc=row["finished_utc"])


def measurement_from_row(row: sqlite3.Row, path: object = "<database>") -> MeasurementRecord:
    """A ``measurements`` row as its record; RecordError naming the row and column when a value
    is ±inf (SQLite stores NaN as NULL): an edited or damaged record, which no output may carry."""
    if any(v.__class__ is float and v - v != 0.0 for v in row):  # ±inf - ±inf is NaN (one pass, no lookups)
        key = next(k for k in row.keys() if isinstance(row[k], float) and not math.isfinite(row[k]))
        raise RecordError(f"{path}: table measurements, row {row['id']}: {key} is {row[key]} "
                          "(not a finite number)")
    def xyz(prefix: str):
        v = (row[f"{prefix}_e"], row[f"{prefix}_n"], row[f"{prefix}_u"])
        return None if v[0] is None else v

    px = None if row["centroid_x_px"] is None else (row["centroid_x_px"], row["centroid_y_px"])
    return MeasurementRecord(
        row["iteration"], row["az_steps"], row["el_steps"], xyz("source"), row["source_az_deg"],
        row["source_el_deg"], xyz("aim"), row["plant_time_s"], centroid_enu=xyz("centroid"), centroid_px=px,
        error_mrad=row["error_mrad"], matched_label=row["matched_label"],
        match_distance=row["match_distance"],
        runner_up_label=row["runner_up_label"], runner_up_distance=row["runner_up_distance"],
        measured_utc=row["measured_utc"], source_pos_enu=xyz("source_pos"), id=int(row["id"]),
        run_id=int(row["run_id"]), campaign_id=int(row["campaign_id"]), heliostat_id=row["heliostat_id"])


def model_from_row(row: sqlite3.Row, path: Path) -> ModelRecord:
    """A ``model_params`` row as its record; RecordError when a JSON column was tampered with."""
    def js(col: str, default=None) -> dict:
        return json_column(path, "model_params", row, col, dict, default)
    return ModelRecord(js("params_json"), js("sigma_json"), row["residual_mrad"], row["n_measurements"],
                       js("detail_json", {}))


class ModelRows:
    """The decoded ``model_params`` rows of one open store, by row id: a model row is written
    once and never changed, and a night asks for the latest models of its whole field at every
    lamp change and campaign — without this, 10,000 rows and their covariances parsed each time
    (issue 42). Holds at most ``kept`` records; the oldest go first."""

    def __init__(self, path: Path, kept: int = 100_000) -> None:
        self.path, self.kept = path, kept
        self._by_id: dict[int, ModelRecord] = {}

    @staticmethod
    def insert(db: sqlite3.Connection, heliostat_id: str, campaign_id: int, run_id: int,
               model: ModelRecord) -> int:
        """Insert ``model``, fitted on run ``run_id``, inside the caller's transaction; its row id
        (:meth:`keep` it once committed)."""
        return int(db.execute(
            "INSERT INTO model_params (heliostat_id, campaign_id, run_id, params_json, sigma_json, "
            "residual_mrad, n_measurements, created_utc, detail_json) VALUES (?,?,?,?,?,?,?,?,?)",
            (heliostat_id, campaign_id, run_id, json.dumps(model.params), json.dumps(model.sigma),
             model.residual_mrad, model.n_measurements, utc_now(), json.dumps(model.detail))).lastrowid)

    def keep(self, row_id: int, record: ModelRecord) -> None:
        """``record``, just written as row ``row_id`` (and committed): kept as if read back,
        without its JSON parsed again (a night's next run of the heliostat asks for it)."""
        self._by_id[row_id] = record
        while len(self._by_id) > self.kept:
            del self._by_id[next(iter(self._by_id))]

    def latest(self, db: sqlite3.Connection, heliostat_ids=None) -> dict[str, ModelRecord]:
        """The latest model of each heliostat that has one (of ``heliostat_ids``, or all): their
        row ids in one query on the index, the rows not decoded before in as few as SQLite's
        parameter limit allows."""
        ids = None if heliostat_ids is None else list(heliostat_ids)
        if ids is not None and len(ids) == 1:  # one heliostat: its rows only, on the index
            rows = db.execute("SELECT MAX(id), heliostat_id FROM model_params WHERE heliostat_id=?", ids)
        else:
            rows = db.execute("SELECT MAX(id), heliostat_id FROM model_params GROUP BY heliostat_id")
        wanted = None if ids is None else set(ids)
        latest = [(int(i), h) for i, h in rows.fetchall()
                  if i is not None and (wanted is None or h in wanted)]
        missing = [i for i, _ in latest if i not in self._by_id]
        for k in range(0, len(missing), 500):
            chunk = missing[k:k + 500]
            for r in db.execute(f"SELECT * FROM model_params WHERE id IN ({','.join('?' * len(chunk))})",
                                chunk).fetchall():
                self.keep(int(r["id"]), model_from_row(r, self.path))
        return {h: self._by_id[i] for i, h in latest}
