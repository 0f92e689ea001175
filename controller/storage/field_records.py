"""The records of a whole field at once: a few queries instead of one per heliostat.

A field of 10,000 heliostats asked one heliostat at a time costs 10,000 queries for its
measurements; this reads them in one query, and writes a field's refitted models in one
transaction (the latest models: :meth:`controller.storage.db.CampaignStore.latest_models`).
"""

from __future__ import annotations

import json

import numpy as np

from controller.calibration.records import MeasurementRecord, ModelRecord, utc_now
from controller.storage.checks import RecordError
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


MAX_SPOT_FROM_AIM_M = 100.0  # a measured centroid lies on its target (geometry.paint_io.MAX_SPOT_OFFSET_M)


def check_fit_inputs(path: object, cfg, history: dict[str, list[MeasurementRecord]]) -> None:
    """Before a fit on stored measurements: each one's values are physical — motor steps inside
    the configured axis' hard range, a unit light-source direction, a centroid on its target
    (within :data:`MAX_SPOT_FROM_AIM_M` of the aim point). RecordError naming the database,
    the measurement and the value (an edited record was fitted with exit 0 before)."""
    for hid, ms in history.items():
        axes = cfg.heliostat(hid).axes
        for m in ms:
            where = f"{path}: table measurements, row {m.id} ({hid})"
            for key, steps, axis in (("az_steps", m.az_steps, axes.azimuth),
                                     ("el_steps", m.el_steps, axes.elevation)):
                if not axis.min_increment <= steps <= axis.max_increment:
                    raise RecordError(f"{where}: {key} {steps} is outside the axis' range "
                                      f"[{axis.min_increment}, {axis.max_increment}]")
            if abs(float(np.linalg.norm(m.source_dir)) - 1.0) > 1e-3:
                raise RecordError(f"{where}: source direction {list(m.source_dir)} is not a unit vector")
            if m.centroid_enu is not None:
                off = float(np.linalg.norm(np.subtract(m.centroid_enu, m.aim_enu)))
                if off > MAX_SPOT_FROM_AIM_M:
                    raise RecordError(f"{where}: centroid lies {off:.4g} m from the aim point (on its "
                                      f"target: at most {MAX_SPOT_FROM_AIM_M:g} m)")
