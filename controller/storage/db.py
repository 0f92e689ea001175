"""Calibration records in SQLite.

One database file holds any number of campaigns. The connection runs in WAL mode with
``synchronous=NORMAL`` … ``FULL`` (durable commits), foreign keys on, and every write inside one
transaction (``with store.tx():``). The schema is versioned with ``PRAGMA user_version`` and
upgraded by the ordered :data:`MIGRATIONS` on open, each migration in its own transaction.

Resumability contract (docs/campaigns.md): a heliostat's whole run — run row, measurements,
corrections, images and fitted model — is committed in ONE transaction by
:meth:`CampaignStore.record_run`. A process killed at any instant therefore leaves either the
complete heliostat record or none of it, and ``UNIQUE(campaign_id, heliostat_id)`` makes a
second insert of the same heliostat impossible.

Conventions of the stored values: positions ENU metres, directions ENU unit vectors,
azimuth clockwise from north in degrees, errors in mrad (reflected-beam angle), times as
ISO-8601 UTC strings (wall clock) and plant seconds (``*_s``, the plant clock).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from controller.errors import InputError

MIGRATIONS: tuple[str, ...] = (
    # v1: the record tables.
    """
    CREATE TABLE campaigns (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL UNIQUE,
        config_path TEXT NOT NULL,
        config_sha256 TEXT NOT NULL,
        light_source TEXT NOT NULL,
        target TEXT NOT NULL,
        simulated INTEGER NOT NULL DEFAULT 0,
        queue_json TEXT NOT NULL,
        started_utc TEXT NOT NULL,
        finished_utc TEXT,
        status TEXT NOT NULL DEFAULT 'running',
        meta_json TEXT NOT NULL DEFAULT '{}'
    );
    CREATE TABLE heliostat_runs (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        heliostat_id TEXT NOT NULL,
        queue_index INTEGER NOT NULL,
        status TEXT NOT NULL,
        final_state TEXT NOT NULL,
        iterations INTEGER NOT NULL,
        error_before_mrad REAL,
        error_after_mrad REAL,
        true_error_before_mrad REAL,
        true_error_after_mrad REAL,
        matched_label TEXT,
        truth_label TEXT,
        fault_cause TEXT,
        fault_state TEXT,
        start_s REAL NOT NULL,
        at_standby_s REAL,
        on_target_s REAL,
        off_target_s REAL,
        end_s REAL NOT NULL,
        finished_utc TEXT NOT NULL,
        UNIQUE (campaign_id, heliostat_id)
    );
    CREATE TABLE measurements (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        iteration INTEGER NOT NULL,
        az_steps INTEGER NOT NULL,
        el_steps INTEGER NOT NULL,
        source_e REAL NOT NULL, source_n REAL NOT NULL, source_u REAL NOT NULL,
        source_az_deg REAL NOT NULL,
        source_el_deg REAL NOT NULL,
        centroid_e REAL, centroid_n REAL, centroid_u REAL,
        centroid_x_px REAL, centroid_y_px REAL,
        aim_e REAL NOT NULL, aim_n REAL NOT NULL, aim_u REAL NOT NULL,
        error_mrad REAL,
        true_error_mrad REAL,
        matched_label TEXT,
        match_distance REAL,
        runner_up_label TEXT,
        runner_up_distance REAL,
        plant_time_s REAL NOT NULL,
        measured_utc TEXT NOT NULL,
        UNIQUE (run_id, iteration)
    );
    CREATE TABLE corrections (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        iteration INTEGER NOT NULL,
        kind TEXT NOT NULL CHECK (kind IN ('coarse', 'fine')),
        daz_deg REAL NOT NULL,
        del_deg REAL NOT NULL,
        daz_steps INTEGER NOT NULL,
        del_steps INTEGER NOT NULL
    );
    CREATE TABLE model_params (
        id INTEGER PRIMARY KEY,
        heliostat_id TEXT NOT NULL,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        params_json TEXT NOT NULL,
        sigma_json TEXT NOT NULL,
        residual_mrad REAL,
        n_measurements INTEGER NOT NULL,
        created_utc TEXT NOT NULL
    );
    CREATE TABLE images (
        id INTEGER PRIMARY KEY,
        measurement_id INTEGER NOT NULL REFERENCES measurements(id),
        kind TEXT NOT NULL,
        path TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        exposure_low_s REAL NOT NULL,
        exposure_high_s REAL NOT NULL
    );
    CREATE INDEX measurements_run ON measurements(run_id);
    CREATE INDEX model_params_heliostat ON model_params(heliostat_id, id);
    """,
)

SCHEMA_VERSION = len(MIGRATIONS)


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


@dataclass
class MeasurementRecord:
    """One beam measurement. Directions are ENU unit vectors, positions ENU metres."""

    iteration: int
    az_steps: int
    el_steps: int
    source_dir: tuple[float, float, float]
    source_az_deg: float
    source_el_deg: float
    aim_enu: tuple[float, float, float]
    plant_time_s: float
    centroid_enu: tuple[float, float, float] | None = None
    centroid_px: tuple[float, float] | None = None
    error_mrad: float | None = None
    true_error_mrad: float | None = None
    matched_label: str | None = None
    match_distance: float | None = None
    runner_up_label: str | None = None
    runner_up_distance: float | None = None
    measured_utc: str = field(default_factory=utc_now)
    images: list[ImageRecord] = field(default_factory=list)


@dataclass
class ImageRecord:
    kind: str  # "low", "high" or "hdr"
    path: str
    sha256: str
    exposures: tuple[float, float]


@dataclass
class CorrectionRecord:
    iteration: int
    kind: str  # "coarse" (library case) or "fine" (centroid offset through the Jacobian)
    daz_deg: float
    del_deg: float
    daz_steps: int
    del_steps: int


@dataclass
class ModelRecord:
    params: dict[str, float]
    sigma: dict[str, float]
    residual_mrad: float | None
    n_measurements: int


@dataclass
class RunRecord:
    """Outcome of one heliostat's calibration cycle, written atomically with its children.

    ``status``: ``calibrated`` (within tolerance), ``not_converged`` (max iterations reached)
    or ``failed`` (fault; ``fault_cause`` says why, ``fault_state`` where)."""

    heliostat_id: str
    queue_index: int
    status: str
    final_state: str
    iterations: int
    start_s: float
    end_s: float
    error_before_mrad: float | None = None
    error_after_mrad: float | None = None
    true_error_before_mrad: float | None = None
    true_error_after_mrad: float | None = None
    matched_label: str | None = None
    truth_label: str | None = None
    fault_cause: str | None = None
    fault_state: str | None = None
    at_standby_s: float | None = None
    on_target_s: float | None = None
    off_target_s: float | None = None
    measurements: list[MeasurementRecord] = field(default_factory=list)
    corrections: list[CorrectionRecord] = field(default_factory=list)
    model: ModelRecord | None = None


class CampaignStore:
    """The SQLite record store. Thread-safe: one connection guarded by a lock.

    Raises :class:`InputError` naming the file when it is not a heliocal database or its
    schema is newer than this program understands.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        try:
            self._db = sqlite3.connect(str(self.path), isolation_level=None,
                                       check_same_thread=False, timeout=10.0)
            self._db.row_factory = sqlite3.Row
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{self.path}: not a usable heliocal database ({exc})") from None

    # -- schema -----------------------------------------------------------------------------
    @property
    def schema_version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def _migrate(self) -> None:
        version = self.schema_version
        if version > SCHEMA_VERSION:
            raise InputError(f"{self.path}: database schema v{version} is newer than this "
                             f"heliocal understands (v{SCHEMA_VERSION})")
        for v in range(version, SCHEMA_VERSION):
            with self.tx() as db:
                for stmt in MIGRATIONS[v].split(";"):
                    if stmt.strip():
                        db.execute(stmt)
                db.execute(f"PRAGMA user_version={v + 1}")

    @contextmanager
    def tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (BEGIN IMMEDIATE … COMMIT, ROLLBACK on any exception)."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> CampaignStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- campaigns --------------------------------------------------------------------------
    def open_campaign(self, name: str, *, config_path: str, config_sha256: str, light_source: str,
                      target: str, queue: list[str], simulated: bool = False,
                      meta: dict | None = None) -> tuple[int, bool]:
        """Return ``(campaign_id, resumed)``. An existing campaign of that name is resumed
        only when its config hash and queue match; otherwise InputError says why."""
        with self.tx() as db:
            row = db.execute("SELECT * FROM campaigns WHERE name=?", (name,)).fetchone()
            if row is not None:
                if row["config_sha256"] != config_sha256:
                    raise InputError(f"{self.path}: campaign {name!r} was started with a different "
                                     f"configuration ({row['config_path']}); use another --db or name")
                if json.loads(row["queue_json"]) != list(queue):
                    raise InputError(f"{self.path}: campaign {name!r} was started with a different "
                                     "heliostat queue; use another --db or name")
                db.execute("UPDATE campaigns SET status='running' WHERE id=? AND status!='finished'",
                           (row["id"],))
                return int(row["id"]), True
            cur = db.execute(
                "INSERT INTO campaigns (name, config_path, config_sha256, light_source, target, "
                "simulated, queue_json, started_utc, meta_json) VALUES (?,?,?,?,?,?,?,?,?)",
                (name, config_path, config_sha256, light_source, target, int(simulated),
                 json.dumps(list(queue)), utc_now(), json.dumps(meta or {})))
            return int(cur.lastrowid), False

    def finish_campaign(self, campaign_id: int, status: str = "finished", meta: dict | None = None) -> None:
        with self.tx() as db:
            if meta is not None:
                old = json.loads(db.execute("SELECT meta_json FROM campaigns WHERE id=?",
                                            (campaign_id,)).fetchone()[0])
                old.update(meta)
                db.execute("UPDATE campaigns SET meta_json=? WHERE id=?", (json.dumps(old), campaign_id))
            db.execute("UPDATE campaigns SET status=?, finished_utc=? WHERE id=?",
                       (status, utc_now(), campaign_id))

    def update_meta(self, campaign_id: int, meta: dict) -> None:
        """Merge ``meta`` into the campaign's metadata (one transaction)."""
        with self.tx() as db:
            old = json.loads(db.execute("SELECT meta_json FROM campaigns WHERE id=?",
                                        (campaign_id,)).fetchone()[0])
            old.update(meta)
            db.execute("UPDATE campaigns SET meta_json=? WHERE id=?", (json.dumps(old), campaign_id))

    def campaign(self, campaign_id: int | None = None) -> sqlite3.Row:
        """The given campaign, or the latest one. InputError when there is none."""
        with self._lock:
            if campaign_id is None:
                row = self._db.execute("SELECT * FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
            else:
                row = self._db.execute("SELECT * FROM campaigns WHERE id=?", (campaign_id,)).fetchone()
        if row is None:
            raise InputError(f"{self.path}: no campaign recorded"
                             + (f" with id {campaign_id}" if campaign_id is not None else ""))
        return row

    def campaign_by_name(self, name: str) -> sqlite3.Row | None:
        with self._lock:
            return self._db.execute("SELECT * FROM campaigns WHERE name=?", (name,)).fetchone()

    def last_end_s(self, name: str) -> float | None:
        """Latest recorded plant time (``end_s``) of campaign ``name``, or None."""
        with self._lock:
            row = self._db.execute("SELECT MAX(r.end_s) FROM heliostat_runs r JOIN campaigns c "
                                   "ON r.campaign_id=c.id WHERE c.name=?", (name,)).fetchone()
        return None if row is None or row[0] is None else float(row[0])

    def done_heliostats(self, campaign_id: int) -> set[str]:
        with self._lock:
            rows = self._db.execute("SELECT heliostat_id FROM heliostat_runs WHERE campaign_id=?",
                                    (campaign_id,)).fetchall()
        return {r[0] for r in rows}

    # -- one heliostat run, atomically ------------------------------------------------------
    def record_run(self, campaign_id: int, run: RunRecord) -> int:
        """Insert the run and all its children in one transaction; returns the run id."""
        with self.tx() as db:
            cur = db.execute(
                "INSERT INTO heliostat_runs (campaign_id, heliostat_id, queue_index, status, "
                "final_state, iterations, error_before_mrad, error_after_mrad, true_error_before_mrad, "
                "true_error_after_mrad, matched_label, truth_label, fault_cause, fault_state, start_s, "
                "at_standby_s, on_target_s, off_target_s, end_s, finished_utc) "
                "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (campaign_id, run.heliostat_id, run.queue_index, run.status, run.final_state,
                 run.iterations, run.error_before_mrad, run.error_after_mrad, run.true_error_before_mrad,
                 run.true_error_after_mrad, run.matched_label, run.truth_label, run.fault_cause,
                 run.fault_state, run.start_s, run.at_standby_s, run.on_target_s, run.off_target_s,
                 run.end_s, utc_now()))
            run_id = int(cur.lastrowid)
            for m in run.measurements:
                c = m.centroid_enu or (None, None, None)
                px = m.centroid_px or (None, None)
                mcur = db.execute(
                    "INSERT INTO measurements (run_id, iteration, az_steps, el_steps, source_e, source_n, "
                    "source_u, source_az_deg, source_el_deg, centroid_e, centroid_n, centroid_u, "
                    "centroid_x_px, centroid_y_px, aim_e, aim_n, aim_u, error_mrad, true_error_mrad, "
                    "matched_label, match_distance, runner_up_label, runner_up_distance, plant_time_s, "
                    "measured_utc) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (run_id, m.iteration, int(m.az_steps), int(m.el_steps), *map(float, m.source_dir),
                     m.source_az_deg, m.source_el_deg, *c, *px, *map(float, m.aim_enu), m.error_mrad,
                     m.true_error_mrad, m.matched_label, m.match_distance, m.runner_up_label,
                     m.runner_up_distance, m.plant_time_s, m.measured_utc))
                for im in m.images:
                    db.execute("INSERT INTO images (measurement_id, kind, path, sha256, exposure_low_s, "
                               "exposure_high_s) VALUES (?,?,?,?,?,?)",
                               (mcur.lastrowid, im.kind, im.path, im.sha256, *im.exposures))
            for k in run.corrections:
                db.execute("INSERT INTO corrections (run_id, iteration, kind, daz_deg, del_deg, daz_steps, "
                           "del_steps) VALUES (?,?,?,?,?,?,?)",
                           (run_id, k.iteration, k.kind, k.daz_deg, k.del_deg, k.daz_steps, k.del_steps))
            if run.model is not None:
                db.execute("INSERT INTO model_params (heliostat_id, campaign_id, run_id, params_json, "
                           "sigma_json, residual_mrad, n_measurements, created_utc) VALUES (?,?,?,?,?,?,?,?)",
                           (run.heliostat_id, campaign_id, run_id, json.dumps(run.model.params),
                            json.dumps(run.model.sigma), run.model.residual_mrad,
                            run.model.n_measurements, utc_now()))
            return run_id

    # -- queries ----------------------------------------------------------------------------
    def runs(self, campaign_id: int) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute("SELECT * FROM heliostat_runs WHERE campaign_id=? ORDER BY queue_index",
                                    (campaign_id,)).fetchall()

    def measurements(self, campaign_id: int | None = None, heliostat_id: str | None = None
                     ) -> list[sqlite3.Row]:
        """Measurements joined with their run's heliostat id and campaign id."""
        sql = ("SELECT m.*, r.heliostat_id, r.campaign_id, c.target AS target, "
               "c.light_source AS light_source "
               "FROM measurements m JOIN heliostat_runs r ON m.run_id=r.id "
               "JOIN campaigns c ON r.campaign_id=c.id WHERE 1=1")
        args: list = []
        if campaign_id is not None:
            sql += " AND r.campaign_id=?"
            args.append(campaign_id)
        if heliostat_id is not None:
            sql += " AND r.heliostat_id=?"
            args.append(heliostat_id)
        with self._lock:
            return self._db.execute(sql + " ORDER BY m.id", args).fetchall()

    def corrections(self, run_id: int) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute("SELECT * FROM corrections WHERE run_id=? ORDER BY id",
                                    (run_id,)).fetchall()

    def images(self, measurement_id: int) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute("SELECT * FROM images WHERE measurement_id=? ORDER BY id",
                                    (measurement_id,)).fetchall()

    def latest_model(self, heliostat_id: str) -> ModelRecord | None:
        """The most recent fitted tracking-error parameters of a heliostat, or None."""
        with self._lock:
            row = self._db.execute("SELECT * FROM model_params WHERE heliostat_id=? ORDER BY id DESC LIMIT 1",
                                   (heliostat_id,)).fetchone()
        if row is None:
            return None
        return ModelRecord(json.loads(row["params_json"]), json.loads(row["sigma_json"]),
                           row["residual_mrad"], row["n_measurements"])

    def count(self, table: str) -> int:
        if table not in ("campaigns", "heliostat_runs", "measurements", "corrections", "model_params",
                         "images"):
            raise ValueError(table)
        with self._lock:
            return int(self._db.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])


def open_existing(path: str | Path) -> CampaignStore:
    """Open a database that must already exist (reports, export): InputError otherwise."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"database not found: {p}")
    return CampaignStore(p)
