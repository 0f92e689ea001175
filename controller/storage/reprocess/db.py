"""The database a reprocessing writes (docs/reprocess.md): a copy of the source's records, its
progress, and at the end the re-analysed measurements and refitted models.

* :func:`create_output` copies the source (SQLite online backup from the read-only connection)
  into a temporary file beside ``--out``, adds the ``reprocess_*`` tables and renames it into
  place: ``--out`` appears whole or not at all.
* Each chunk of pairs is committed in one transaction (``reprocess_pairs``), each batch of
  refits likewise (``reprocess_models``); a rerun skips what is there.
* :meth:`ReprocessDb.apply` then writes, in ONE transaction, the new values into
  ``measurements`` and a new ``model_params`` row per refitted heliostat. Until then the record
  tables are exactly the source's.

The ``reprocess_*`` tables are created here, beside the campaign schema (like the simulated
plant's ``sim_truth``), not by its migrations.
"""

from __future__ import annotations

import json
import os
import sqlite3
from pathlib import Path

from controller.calibration.records import MeasurementRecord, utc_now
from controller.calibration.reprocess.tasks import PairResult, RefitResult
from controller.errors import InputError
from controller.storage.db import CampaignStore
from controller.storage.lock import CampaignLock

TABLES = """
CREATE TABLE IF NOT EXISTS reprocess_run (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    source TEXT NOT NULL,
    source_fingerprint TEXT NOT NULL,
    options_json TEXT NOT NULL,
    started_utc TEXT NOT NULL,
    finished_utc TEXT,
    status TEXT NOT NULL DEFAULT 'running',
    summary_json TEXT
);
CREATE TABLE IF NOT EXISTS reprocess_pairs (
    measurement_id INTEGER PRIMARY KEY REFERENCES measurements(id),
    heliostat_id TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('ok', 'no_beam', 'missing', 'unreadable')),
    detail TEXT NOT NULL,
    centroid_x_px REAL, centroid_y_px REAL,
    centroid_e REAL, centroid_n REAL, centroid_u REAL,
    error_mrad REAL,
    matched INTEGER NOT NULL,
    matched_label TEXT, match_distance REAL, runner_up_label TEXT, runner_up_distance REAL,
    old_centroid_e REAL, old_centroid_n REAL, old_centroid_u REAL,
    old_error_mrad REAL
);
CREATE TABLE IF NOT EXISTS reprocess_models (
    heliostat_id TEXT PRIMARY KEY,
    refit INTEGER NOT NULL,
    changed INTEGER NOT NULL,
    old_params_json TEXT, old_sigma_json TEXT,
    new_params_json TEXT, new_sigma_json TEXT,
    new_residual_mrad REAL, new_n_measurements INTEGER, new_detail_json TEXT,
    moved_json TEXT NOT NULL,
    old_predicted_mrad REAL, new_predicted_mrad REAL
);
"""


def create_output(source: CampaignStore, out: Path, source_fingerprint: str, options: dict) -> None:
    """Write ``out``: the source's records plus the empty progress tables (module docstring).
    Nothing is left behind on failure."""
    tmp = out.with_name(f".{out.name}.partial")
    for p in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
        p.unlink(missing_ok=True)
    try:
        dst = sqlite3.connect(str(tmp), isolation_level=None)
        try:
            source.backup(dst)
            dst.execute("PRAGMA journal_mode=DELETE")
            dst.executescript(f"BEGIN; {TABLES} COMMIT;")
            dst.execute("INSERT INTO reprocess_run (id, source, source_fingerprint, options_json, "
                        "started_utc) VALUES (1, ?, ?, ?, ?)",
                        (str(source.path), source_fingerprint, json.dumps(options, sort_keys=True),
                         utc_now()))
        finally:
            dst.close()
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def open_output(source: CampaignStore, out: Path, source_fingerprint: str, options: dict) -> ReprocessDb:
    """Create ``out`` from ``source`` or reopen it to continue: its lock is taken first (one
    reprocessing or campaign at a time, :class:`DatabaseBusy` otherwise), and an existing
    ``out`` must come from the same source, unchanged, with the same options."""
    lock = CampaignLock(out)
    lock.acquire("reprocess")
    try:
        if out.exists():
            _check_output(out)  # read-only: a file that is not a reprocessing output is never written
        else:
            create_output(source, out, source_fingerprint, options)
        db = ReprocessDb(out, lock)
    except BaseException:
        lock.release()
        raise
    info = db.run_info()
    if info["source_fingerprint"] != source_fingerprint:
        db.close()
        raise InputError(f"--out {out}: was started from {info['source']} as it was then; that database "
                         "has changed since (or is another one): choose a new --out")
    if info["options"] != options:
        db.close()
        raise InputError(f"--out {out}: was started with {json.dumps(info['options'], sort_keys=True)}; "
                         "rerun with the same --since and --images, or choose a new --out")
    return db


def _check_output(out: Path) -> None:
    """An existing ``--out`` must be a reprocessing output (checked without writing to it)."""
    refusal = InputError(f"--out {out}: exists and is not a reprocessing output; choose a new file "
                         "(it is never overwritten)")
    if not out.is_file() or out.stat().st_size == 0:
        raise refusal
    try:
        with CampaignStore(out, readonly=True) as store:
            if not store.query("SELECT name FROM sqlite_master WHERE name='reprocess_run'"):
                raise refusal
    except InputError as exc:
        if exc is refusal:
            raise
        raise InputError(f"--out {out}: exists and is not a reprocessing output ({exc}); choose a new file "
                         "(it is never overwritten)") from None


class ReprocessDb:
    """The output database while reprocessing: the record store plus its ``reprocess_*`` tables.
    Use :func:`open_output`."""

    def __init__(self, out: Path, lock: CampaignLock) -> None:
        self.lock = lock
        self.store = CampaignStore(out)
        if not self.store.query("SELECT name FROM sqlite_master WHERE name='reprocess_run'"):
            self.close()
            raise InputError(f"--out {out}: exists and is not a reprocessing output; choose a new file "
                             "(it is never overwritten)")

    def close(self) -> None:
        self.store.close()
        self.lock.release()

    def __enter__(self) -> ReprocessDb:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def run_info(self) -> dict:
        r = self.store.query("SELECT * FROM reprocess_run WHERE id=1")[0]
        return {"source": r["source"], "source_fingerprint": r["source_fingerprint"],
                "options": json.loads(r["options_json"]), "status": r["status"],
                "summary": json.loads(r["summary_json"]) if r["summary_json"] else None}

    # -- progress ---------------------------------------------------------------------------
    def done_pairs(self) -> set[int]:
        return {int(r[0]) for r in self.store.query("SELECT measurement_id FROM reprocess_pairs")}

    def record_pairs(self, results: list[PairResult], old: dict[int, MeasurementRecord]) -> None:
        """One chunk's results, in one transaction."""
        with self.store.tx() as db:
            for r in results:
                m = old[r.measurement_id]
                c = r.centroid_enu or (None, None, None)
                px = r.centroid_px or (None, None)
                oc = m.centroid_enu or (None, None, None)
                db.execute(
                    "INSERT INTO reprocess_pairs VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (r.measurement_id, m.heliostat_id, r.status, r.detail, *px, *c, r.error_mrad,
                     int(r.matched), r.matched_label, r.match_distance, r.runner_up_label,
                     r.runner_up_distance, *oc, m.error_mrad))

    def pair_rows(self) -> list[sqlite3.Row]:
        return self.store.query("SELECT * FROM reprocess_pairs ORDER BY measurement_id")

    def pair_results(self) -> dict[int, PairResult]:
        """Every committed pair result by measurement id."""
        def xyz(r, a: str, b: str, c: str):
            return None if r[a] is None else (r[a], r[b], r[c])

        return {int(r["measurement_id"]): PairResult(
            int(r["measurement_id"]), r["status"], r["detail"],
            None if r["centroid_x_px"] is None else (r["centroid_x_px"], r["centroid_y_px"]),
            xyz(r, "centroid_e", "centroid_n", "centroid_u"), r["error_mrad"], bool(r["matched"]),
            r["matched_label"], r["match_distance"], r["runner_up_label"], r["runner_up_distance"])
            for r in self.pair_rows()}

    def done_models(self) -> set[str]:
        return {str(r[0]) for r in self.store.query("SELECT heliostat_id FROM reprocess_models")}

    def record_models(self, results: list[RefitResult], old: dict) -> None:
        """A batch of refits, in one transaction (``old``: heliostat → its source model)."""
        with self.store.tx() as db:
            for r in results:
                o, n = old.get(r.heliostat_id), r.model
                db.execute(
                    "INSERT INTO reprocess_models VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (r.heliostat_id, int(n is not None), int(r.changed),
                     None if o is None else json.dumps(o.params), None if o is None else json.dumps(o.sigma),
                     None if n is None else json.dumps(n.params), None if n is None else json.dumps(n.sigma),
                     None if n is None else n.residual_mrad, None if n is None else n.n_measurements,
                     None if n is None else json.dumps(n.detail), json.dumps(r.moved, sort_keys=True),
                     r.old_predicted_mrad, r.new_predicted_mrad))

    def model_rows(self) -> list[sqlite3.Row]:
        return self.store.query("SELECT * FROM reprocess_models ORDER BY heliostat_id")

    # -- the end ----------------------------------------------------------------------------
    def apply(self, latest_run: dict[str, int], summary: dict) -> None:
        """Write the re-analysed measurements (pairs ``ok`` or ``no_beam``; a missing or
        unreadable pair keeps its stored values) and one new model row per refitted heliostat
        (on its latest run), and mark the run finished: ONE transaction."""
        with self.store.tx() as db:
            db.execute(
                "UPDATE measurements SET (centroid_x_px, centroid_y_px, centroid_e, centroid_n, centroid_u, "
                "error_mrad) = (SELECT p.centroid_x_px, p.centroid_y_px, p.centroid_e, p.centroid_n, "
                "p.centroid_u, p.error_mrad FROM reprocess_pairs p WHERE p.measurement_id = measurements.id) "
                "WHERE id IN (SELECT measurement_id FROM reprocess_pairs WHERE status IN ('ok', 'no_beam'))")
            db.execute(
                "UPDATE measurements SET (matched_label, match_distance, runner_up_label, "
                "runner_up_distance) = (SELECT p.matched_label, p.match_distance, p.runner_up_label, "
                "p.runner_up_distance "
                "FROM reprocess_pairs p WHERE p.measurement_id = measurements.id) "
                "WHERE id IN (SELECT measurement_id FROM reprocess_pairs WHERE matched = 1 "
                "OR status = 'no_beam')")
            stamp = utc_now()
            refits = db.execute("SELECT * FROM reprocess_models WHERE refit = 1 ORDER BY heliostat_id")
            for r in refits.fetchall():
                run_id = latest_run[r["heliostat_id"]]
                cid = db.execute("SELECT campaign_id FROM heliostat_runs WHERE id=?", (run_id,)).fetchone()[0]
                db.execute("INSERT INTO model_params (heliostat_id, campaign_id, run_id, params_json, "
                           "sigma_json, residual_mrad, n_measurements, created_utc, detail_json) "
                           "VALUES (?,?,?,?,?,?,?,?,?)",
                           (r["heliostat_id"], cid, run_id, r["new_params_json"], r["new_sigma_json"],
                            r["new_residual_mrad"], r["new_n_measurements"], stamp, r["new_detail_json"]))
            db.execute("UPDATE reprocess_run SET status='finished', finished_utc=?, summary_json=? "
                       "WHERE id=1", (stamp, json.dumps(summary, sort_keys=True)))
