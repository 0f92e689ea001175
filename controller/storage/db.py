"""Calibration records in SQLite.

One database file holds any number of campaigns. The connection runs in WAL mode with
``synchronous=FULL`` (durable commits), foreign keys on, and every write inside one
transaction (``with store.tx():``). The schema is versioned with ``PRAGMA user_version`` and
upgraded by the ordered :data:`MIGRATIONS` on open, all of them in one transaction (a failed
upgrade changes nothing). A file the open created is removed again when the open is refused,
and a database's folder is never created.

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
import os
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import quote

from controller.calibration.records import (
    CAMPAIGN_STATUSES,
    CampaignRecord,
    CorrectionRecord,
    ImageRecord,
    MeasurementRecord,
    ModelRecord,
    RunRecord,
    utc_now,
)
from controller.errors import InputError
from controller.io.files import check_regular
from controller.io.text_numbers import is_ascii_index
from controller.storage.checks import (
    CheckedConnection,
    check_pages,
    check_schema,
    enum_column,
    json_column,
    resolved_image_path,
)
from controller.storage.db_file import check_foreign, records_nothing, remove_new_database, upgrade
from controller.storage.images import insert_images
from controller.storage.lock import CampaignLock
from controller.storage.rows import ModelRows, campaign_from_row, measurement_from_row, run_from_row
from controller.storage.schema import MIGRATIONS, SCHEMA_VERSION
from controller.storage.searches import insert_search


class CampaignStore:
    """The SQLite record store. Thread-safe: one connection guarded by a lock.

    ``readonly``: open an existing database without changing it (reports, export): no
    migration, no file created. A writer creates and upgrades the schema, and
    :meth:`open_campaign` takes the database's exclusive campaign lock
    (:class:`controller.storage.lock.CampaignLock`) until :meth:`close`.

    Raises :class:`InputError` naming the file when it is not a heliocal database (another
    program's SQLite file is refused, never written into), its schema is newer than this
    program understands, or a table or column of the schema is missing; records read later are
    checked on the way out (:mod:`controller.storage.checks`). A read-only database file (or
    folder) is opened immutable for reading: no one with our rights can be writing it.
    """

    def __init__(self, path: str | Path, *, readonly: bool = False) -> None:
        self.path = Path(path)
        self.readonly = readonly
        self._lock = threading.RLock()
        self.campaign_lock = CampaignLock(self.path)
        self._models = ModelRows(self.path)  # the records are shared: never change one
        check_regular(self.path, "database")  # a FIFO would block sqlite's first read
        # a new (or empty) file this open creates is removed again when the open is refused
        self._existed = self.path.exists()
        self._created = not readonly and (not self._existed or self.path.stat().st_size == 0)
        self._db: sqlite3.Connection | None = None
        try:
            if readonly:
                self._db = self._open_readonly()
            else:
                if not self.path.parent.is_dir():
                    raise InputError(f"{self.path}: folder {self.path.parent} does not exist "
                                     "(create it first)")
                self._db = sqlite3.connect(str(self.path), isolation_level=None, check_same_thread=False,
                                           timeout=10.0, factory=CheckedConnection)
                self._db.path = self.path
            self._db.row_factory = sqlite3.Row
            check_foreign(self._db, self.path, self.readonly)
            if not readonly:
                self._db.execute("PRAGMA foreign_keys=ON")
                upgrade(self, MIGRATIONS)  # before WAL: a refused upgrade leaves the journal mode as it was
                self._db.execute("PRAGMA journal_mode=WAL")
                self._db.execute("PRAGMA synchronous=FULL")
            elif self.schema_version > SCHEMA_VERSION:
                raise InputError(f"{self.path}: database schema v{self.schema_version} is newer than this "
                                 f"heliocal understands (v{SCHEMA_VERSION})")
            if not readonly or self.schema_version == SCHEMA_VERSION:
                check_schema(self._db, self.path, MIGRATIONS)
            if readonly:
                check_pages(self._db, self.path)
        except sqlite3.DatabaseError as exc:
            self._abandon()
            raise InputError(f"{self.path}: not a usable heliocal database ({exc})") from None
        except BaseException:
            self._abandon()
            raise

    def _abandon(self) -> None:
        """A refused open: close the connection; a file this open created is removed."""
        if self._db is not None:
            self._db.close()
        if self._created:
            remove_new_database(self.path, self._existed)

    def _open_readonly(self) -> sqlite3.Connection:
        try:
            return self._connect_readonly("")
        except InputError:
            if os.access(self.path, os.W_OK) and os.access(self.path.parent, os.W_OK):
                raise
        # A WAL database needs its -shm file; without write access to create it, read the file as
        # it is (nobody with our rights can be writing it).
        return self._connect_readonly("&immutable=1")

    def _connect_readonly(self, options: str) -> sqlite3.Connection:
        db = sqlite3.connect(f"file:{quote(str(self.path))}?mode=ro{options}", uri=True, isolation_level=None,
                             check_same_thread=False, timeout=10.0, factory=CheckedConnection)
        db.path = self.path
        try:
            db.execute("PRAGMA user_version").fetchone()
        except BaseException:
            db.close()
            raise
        return db

    # -- schema -----------------------------------------------------------------------------
    @property
    def schema_version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    @contextmanager
    def tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (BEGIN IMMEDIATE … COMMIT, ROLLBACK on any exception).

        A Ctrl-C (SIGTERM) raised between the body and COMMIT, or cutting a ROLLBACK short, leaves
        the transaction open: it is rolled back, here or by the next one; never half a write."""
        with self._lock:
            if self._db.in_transaction:  # only an interrupted transaction is open here: undone
                self._db.execute("ROLLBACK")
            try:
                self._db.execute("BEGIN IMMEDIATE")
                yield self._db
                self._db.execute("COMMIT")
            finally:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")

    def close(self, refused: BaseException | None = None) -> None:
        """Close; after a refusal (an InputError) a database this open created, still empty, goes."""
        with self._lock:
            if self._db is None:  # closed already
                return
            discard = isinstance(refused, InputError) and self._created and records_nothing(self._db)
            self._db.close()
            if discard:
                self._db = None
                remove_new_database(self.path, self._existed)
            self.campaign_lock.release()

    def __enter__(self) -> CampaignStore:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(exc)

    # -- campaigns --------------------------------------------------------------------------
    def open_campaign(self, name: str, *, config_path: str, config_sha256: str, light_source: str,
                      target: str, queue: list[str], meta: dict | None = None) -> tuple[int, bool]:
        """Return ``(campaign_id, resumed)``. An existing campaign of that name is resumed
        only when its config hash and queue match; otherwise InputError says why. Takes the
        database's campaign lock first (:class:`DatabaseBusy` names a live owner)."""
        self.campaign_lock.acquire()
        with self.tx() as db:
            row = db.execute("SELECT * FROM campaigns WHERE name=?", (name,)).fetchone()
            if row is not None:
                if row["config_sha256"] != config_sha256:
                    raise InputError(f"{self.path}: campaign {name!r} was started with a different "
                                     f"configuration ({row['config_path']}); use another --db or name")
                if json_column(self.path, "campaigns", row, "queue_json", list) != list(queue):
                    raise InputError(f"{self.path}: campaign {name!r} was started with a different "
                                     "heliostat queue; use another --db or name")
                db.execute("UPDATE campaigns SET status='running', cause=NULL "
                           "WHERE id=? AND status!='finished'", (row["id"],))
                return int(row["id"]), True
            cur = db.execute(
                "INSERT INTO campaigns (name, config_path, config_sha256, light_source, target, "
                "queue_json, started_utc, meta_json) VALUES (?,?,?,?,?,?,?,?)",
                (name, config_path, config_sha256, light_source, target, json.dumps(list(queue)), utc_now(),
                 json.dumps(meta or {})))
            return int(cur.lastrowid), False

    def finish_campaign(self, campaign_id: int, status: str, cause: str | None = None) -> None:
        """Record how the campaign's session ended (see :data:`CAMPAIGN_STATUSES`) and why."""
        if status not in CAMPAIGN_STATUSES:
            raise ValueError(f"campaign status must be one of {CAMPAIGN_STATUSES}, got {status!r}")
        with self.tx() as db:
            db.execute("UPDATE campaigns SET status=?, cause=?, finished_utc=? WHERE id=?",
                       (status, cause, utc_now(), campaign_id))

    def update_meta(self, campaign_id: int, meta: dict) -> None:
        """Merge ``meta`` into the campaign's metadata (one transaction)."""
        with self.tx() as db:
            row = db.execute("SELECT id, meta_json FROM campaigns WHERE id=?", (campaign_id,)).fetchone()
            old = json_column(self.path, "campaigns", row, "meta_json", dict, {})
            old.update(meta)
            db.execute("UPDATE campaigns SET meta_json=? WHERE id=?", (json.dumps(old), campaign_id))

    def campaign(self, campaign_id: int | None = None) -> CampaignRecord:
        """The given campaign, or the latest one. InputError when there is none."""
        with self._lock:
            if campaign_id is None:
                row = self._db.execute("SELECT * FROM campaigns ORDER BY id DESC LIMIT 1").fetchone()
            else:
                row = self._db.execute("SELECT * FROM campaigns WHERE id=?", (campaign_id,)).fetchone()
        if row is None:
            raise InputError(f"{self.path}: no campaign recorded"
                             + (f" with id {campaign_id}" if campaign_id is not None else ""))
        return campaign_from_row(row, self.path)

    def campaigns(self) -> list[CampaignRecord]:
        """Every campaign, oldest first."""
        with self._lock:
            rows = self._db.execute("SELECT * FROM campaigns ORDER BY id").fetchall()
        return [campaign_from_row(r, self.path) for r in rows]

    def find_campaign(self, ref: str | int | None) -> CampaignRecord:
        """A campaign by name or id (a name wins over an id of the same text); the latest for
        None. InputError names the database and the reference when there is none."""
        if ref is None:
            return self.campaign()
        by_name = self.campaign_by_name(str(ref))
        if by_name is not None:
            return by_name
        if is_ascii_index(str(ref)):
            return self.campaign(int(ref))
        raise InputError(f"{self.path}: no campaign named {ref!r} (see heliocal campaign list)")

    def campaign_by_name(self, name: str) -> CampaignRecord | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM campaigns WHERE name=?", (name,)).fetchone()
        return None if row is None else campaign_from_row(row, self.path)

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
        model_row = None
        with self.tx() as db:
            cur = db.execute(
                "INSERT INTO heliostat_runs (campaign_id, heliostat_id, queue_index, status, "
                "final_state, iterations, error_before_mrad, error_after_mrad, matched_label, "
                "fault_cause, fault_state, start_s, at_standby_s, on_target_s, off_target_s, end_s, "
                "finished_utc) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (campaign_id, run.heliostat_id, run.queue_index, run.status, run.final_state,
                 run.iterations, run.error_before_mrad, run.error_after_mrad, run.matched_label,
                 run.fault_cause, run.fault_state, run.start_s, run.at_standby_s, run.on_target_s,
                 run.off_target_s, run.end_s, utc_now()))
            run_id = int(cur.lastrowid)
            for m in run.measurements:
                c = m.centroid_enu or (None, None, None)
                px = m.centroid_px or (None, None)
                mcur = db.execute(
                    "INSERT INTO measurements (run_id, iteration, az_steps, el_steps, source_e, source_n, "
                    "source_u, source_az_deg, source_el_deg, centroid_e, centroid_n, centroid_u, "
                    "centroid_x_px, centroid_y_px, aim_e, aim_n, aim_u, error_mrad, matched_label, "
                    "match_distance, runner_up_label, runner_up_distance, plant_time_s, measured_utc, "
                    "source_pos_e, source_pos_n, source_pos_u, target) "
                    "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,"
                    "(SELECT target FROM campaigns WHERE id=?))",
                    (run_id, m.iteration, int(m.az_steps), int(m.el_steps), *map(float, m.source_dir),
                     m.source_az_deg, m.source_el_deg, *c, *px, *map(float, m.aim_enu), m.error_mrad,
                     m.matched_label, m.match_distance, m.runner_up_label, m.runner_up_distance,
                     m.plant_time_s, m.measured_utc, *(m.source_pos_enu or (None, None, None)),
                     campaign_id))
                insert_images(db, self.path, "images", "measurement_id", mcur.lastrowid, m.images)
            insert_images(db, self.path, "run_frames", "run_id", run_id, run.frames)  # gave no measurement
            insert_search(db, run_id, run.search)
            for k in run.corrections:
                db.execute("INSERT INTO corrections (run_id, iteration, kind, daz_deg, del_deg, daz_steps, "
                           "del_steps) VALUES (?,?,?,?,?,?,?)",
                           (run_id, k.iteration, k.kind, k.daz_deg, k.del_deg, k.daz_steps, k.del_steps))
            if run.model is not None:
                model_row = self._models.insert(db, run.heliostat_id, campaign_id, run_id, run.model)
        if model_row is not None:  # committed: the next run of this heliostat reads it undecoded
            with self._lock:
                self._models.keep(int(model_row), run.model)
        return run_id

    # -- queries ----------------------------------------------------------------------------
    def runs(self, campaign_id: int) -> list[RunRecord]:
        """Every recorded run of a campaign in queue order (without children: see
        :meth:`measurements` and :meth:`corrections`)."""
        with self._lock:
            rows = self._db.execute("SELECT * FROM heliostat_runs WHERE campaign_id=? ORDER BY queue_index",
                                    (campaign_id,)).fetchall()
        return [run_from_row(r, self.path) for r in rows]

    def measurements(self, campaign_id: int | None = None, heliostat_id: str | None = None
                     ) -> list[MeasurementRecord]:
        """Measurements in recording order, with their run id and heliostat id set."""
        sql = ("SELECT m.*, r.heliostat_id, r.campaign_id FROM measurements m "
               "JOIN heliostat_runs r ON m.run_id=r.id WHERE 1=1")
        args: list = []
        if campaign_id is not None:
            sql += " AND r.campaign_id=?"
            args.append(campaign_id)
        if heliostat_id is not None:
            sql += " AND r.heliostat_id=?"
            args.append(heliostat_id)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY m.id", args).fetchall()
        return [measurement_from_row(r, self.path) for r in rows]

    def corrections(self, run_id: int) -> list[CorrectionRecord]:
        rows = self.query("SELECT * FROM corrections WHERE run_id=? ORDER BY id", (run_id,))
        return [CorrectionRecord(r["iteration"],
                                 enum_column(self.path, "corrections", r, "kind", ("coarse", "fine")),
                                 r["daz_deg"], r["del_deg"], r["daz_steps"],
                                 r["del_steps"]) for r in rows]

    def images(self, measurement_id: int) -> list[ImageRecord]:
        rows = self.query("SELECT * FROM images WHERE measurement_id=? ORDER BY id", (measurement_id,))
        return [ImageRecord(enum_column(self.path, "images", r, "kind", ("low", "high")),
                            resolved_image_path(self.path, r["path"]), r["sha256"],
                            (r["exposure_low_s"], r["exposure_high_s"])) for r in rows]

    def latest_model(self, heliostat_id: str) -> ModelRecord | None:
        """The most recent fitted tracking-error parameters of a heliostat, or None."""
        return self.latest_models([heliostat_id]).get(heliostat_id)

    def with_models(self, heliostat_ids) -> set[str]:
        """Those of ``heliostat_ids`` that have a fitted model, nothing decoded (a campaign's alarm
        watch asks at its start: thousands of models are written since the last decode)."""
        wanted = set(heliostat_ids)
        return {h for (h,) in self.query("SELECT DISTINCT heliostat_id FROM model_params") if h in wanted}

    def latest_models(self, heliostat_ids=None) -> dict[str, ModelRecord]:
        """The latest model of each heliostat that has one (of ``heliostat_ids``, or all); rows
        read before are not parsed again, and their records are shared (:class:`ModelRows`)."""
        with self._lock:
            return self._models.latest(self._db, heliostat_ids)

    def query(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        """Rows of one read-only SELECT (for the storage modules beside this one)."""
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def backup(self, target: sqlite3.Connection) -> None:
        """Copy the whole database into ``target`` (SQLite's online backup: a consistent snapshot,
        also from a read-only store)."""
        with self._lock:
            self._db.backup(target)

    def count(self, table: str) -> int:
        if table not in ("campaigns", "heliostat_runs", "measurements", "corrections", "model_params",
                         "images"):
            raise ValueError(table)
        return int(self.query(f"SELECT COUNT(*) FROM {table}")[0][0])


def open_existing(path: str | Path) -> CampaignStore:
    """Open a database that must already exist, read-only (reports, export): InputError otherwise."""
    p = Path(path)
    check_regular(p, "database")  # a FIFO, a folder, a device; unreadable: named
    if not p.is_file():
        raise InputError(f"database not found: {p}")
    return CampaignStore(p, readonly=True)
