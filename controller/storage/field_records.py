"""The records of a whole field at once: a few queries instead of one per heliostat.

A field of 10,000 heliostats asked one heliostat at a time costs 10,000 queries for its
measurements; this reads them in one query, and writes a field's refitted models in one
transaction (the latest models: :meth:`controller.storage.db.CampaignStore.latest_models`).
"""

from __future__ import annotations

import json

from controller.calibration.records import MeasurementRecord, ModelRecord, utc_now
from controller.storage.db import CampaignStore
from controller.storage.rows import measurement_from_row


def measurements_by_heliostat(store: CampaignStore, heliostat_ids=None) -> dict[str, list[MeasurementRecord]]:
    """Every measurement of each heliostat (of ``heliostat_ids``, or all), in recording order,
    with its run, campaign and heliostat ids set."""
    rows = store.query("SELECT m.*, r.heliostat_id, r.campaign_id FROM measurements m "
                       "JOIN heliostat_runs r ON m.run_id=r.id ORDER BY m.id")
    wanted = None if heliostat_ids is None else set(heliostat_ids)
    out: dict[str, list[MeasurementRecord]] = {}
    for r in rows:
        if wanted is None or r["heliostat_id"] in wanted:
            out.setdefault(r["heliostat_id"], []).append(measurement_from_row(r, store.path))
    return out


def record_models(store: CampaignStore, models: dict[str, tuple[MeasurementRecord, ModelRecord]]) -> int:
    """Store each heliostat's refitted model (``{id: (its latest measurement, model)}``) as the
    model of that measurement's run, in one transaction; returns how many."""
    with store.tx() as db:
        for hid, (m, model) in models.items():
            db.execute("INSERT INTO model_params (heliostat_id, campaign_id, run_id, params_json, "
                       "sigma_json, residual_mrad, n_measurements, created_utc, detail_json) "
                       "VALUES (?,?,?,?,?,?,?,?,?)",
                       (hid, m.campaign_id, m.run_id, json.dumps(model.params), json.dumps(model.sigma),
                        model.residual_mrad, model.n_measurements, utc_now(), json.dumps(model.detail)))
    return len(models)
