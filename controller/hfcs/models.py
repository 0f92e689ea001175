"""The heliostats' latest models with their versions, for the HFCS to pull
(``heliocal export models``; docs/plant-integration.md, "The HFCS interface").

A model's ``version`` counts the models fitted for that heliostat so far (1 for its first): a
new one means the HFCS should pull it. ``model_id`` is its row in the database. ``terms`` are
the tracking model's parameters by key (mrad or mm, docs/tracking-model.md) and ``sigma`` their
1-σ.
"""

from __future__ import annotations

import csv
import io

from controller.storage.checks import json_column
from controller.storage.db import CampaignStore

CSV_FIXED = ("heliostat", "version", "model_id", "created_utc", "n_measurements", "residual_mrad")


def model_versions(store: CampaignStore, heliostat_ids: list[str] | None = None) -> list[dict]:
    """Each heliostat's latest model with its version, by heliostat id."""
    rows = store.query(
        "SELECT m.*, (SELECT COUNT(*) FROM model_params p WHERE p.heliostat_id = m.heliostat_id "
        "AND p.id <= m.id) AS version FROM model_params m WHERE m.id IN "
        "(SELECT MAX(id) FROM model_params GROUP BY heliostat_id) ORDER BY m.heliostat_id")
    wanted = None if heliostat_ids is None else set(heliostat_ids)
    out = []
    for r in rows:
        if wanted is not None and r["heliostat_id"] not in wanted:
            continue
        out.append({"heliostat": r["heliostat_id"], "version": int(r["version"]), "model_id": int(r["id"]),
                    "created_utc": r["created_utc"], "n_measurements": int(r["n_measurements"]),
                    "residual_mrad": r["residual_mrad"],
                    "terms": json_column(store.path, "model_params", r, "params_json", dict),
                    "sigma": json_column(store.path, "model_params", r, "sigma_json", dict)})
    return out


def models_csv(models: list[dict]) -> str:
    """One row per heliostat: :data:`CSV_FIXED`, then each term and its σ (``sigma_<term>``)."""
    terms = sorted({k for m in models for k in m["terms"]})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*CSV_FIXED, *terms, *(f"sigma_{t}" for t in terms)])
    for m in models:
        w.writerow([*(m[k] if m[k] is not None else "" for k in CSV_FIXED),
                    *(m["terms"].get(t, "") for t in terms),
                    *("" if m["sigma"].get(t) is None else m["sigma"][t] for t in terms)])
    return buf.getvalue()
