"""The ``beam_searches`` table: each heliostat's beam search (``calibration.search``,
docs/commissioning.md "First light on a new field"), one row per run that had one."""

from __future__ import annotations

import json
import sqlite3

from controller.calibration.records import SearchRecord
from controller.storage.checks import has_table


def insert_search(db: sqlite3.Connection, run_id: int, search: SearchRecord | None) -> None:
    """Write a run's search inside the run's own transaction (nothing without one)."""
    if search is None:
        return
    miss = search.miss_m or (None, None)
    db.execute("INSERT INTO beam_searches (run_id, looks, skipped, seconds, found, miss_u_m, miss_v_m, "
               "offsets_json) VALUES (?,?,?,?,?,?,?,?)",
               (run_id, search.looks, search.skipped, float(search.seconds), int(search.found), *miss,
                json.dumps([list(o) for o in search.offsets_m])))


def campaign_searches(store, campaign_id: int) -> dict[str, SearchRecord]:
    """Heliostat → its run's :class:`SearchRecord` in a campaign (``store`` a
    :class:`controller.storage.db.CampaignStore`); empty for a store without the table."""
    if not has_table(store, "beam_searches"):
        return {}
    rows = store.query("SELECT r.heliostat_id, s.* FROM beam_searches s "
                       "JOIN heliostat_runs r ON s.run_id=r.id WHERE r.campaign_id=? ORDER BY r.queue_index",
                       (campaign_id,))
    return {r["heliostat_id"]: SearchRecord(
        int(r["looks"]), int(r["skipped"]), float(r["seconds"]), bool(r["found"]),
        [tuple(o) for o in json.loads(r["offsets_json"])],
        None if r["miss_u_m"] is None else (float(r["miss_u_m"]), float(r["miss_v_m"]))) for r in rows}
