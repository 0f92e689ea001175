"""What archive reprocessing reads from a record store: the campaigns, every measurement with its
archived frame pair, and each heliostat's current model (docs/reprocess.md).

The store is opened read-only (:func:`controller.storage.db.open_existing`). The unit of records
is the campaign (a planned night's passes are campaigns too); a frame pair belongs to one
measurement of one heliostat run of one campaign. This module is all reprocessing reads.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from controller.calibration.reprocess.plan import Archive, StoredCampaign, StoredPair
from controller.storage.checks import resolved_image_path
from controller.storage.db import CampaignStore


def read_archive(store: CampaignStore) -> Archive:
    """Read ``store`` (opened read-only) in one pass over each table."""
    campaigns = {}
    for c in store.campaigns():
        reg = c.meta.get("camera_registration")
        reg_json = json.dumps(reg, sort_keys=True) if isinstance(reg, dict) and reg else ""
        campaigns[c.id] = StoredCampaign(c.id, c.name, c.config_path, c.config_sha256, c.target, reg_json)
    measurements = store.measurements()
    files: dict[int, dict[str, tuple]] = {}
    for r in store.query("SELECT measurement_id, kind, path, sha256, exposure_low_s, exposure_high_s "
                         "FROM images WHERE kind IN ('low', 'high') ORDER BY id"):
        # Stored relative to the database (or absolute, before that): as the frame lies now.
        files.setdefault(int(r[0]), {})[r[1]] = (resolved_image_path(store.path, str(r[2])), str(r[3]),
                                                 (float(r[4]), float(r[5])))
    pairs = {mid: StoredPair(f["low"][0], f["high"][0], f["low"][1], f["high"][1], f["low"][2])
             for mid, f in files.items() if "low" in f and "high" in f}
    heliostats = sorted({m.heliostat_id for m in measurements})
    models = {h: m for h in heliostats if (m := store.latest_model(h)) is not None}
    latest_run = {str(r[0]): int(r[1]) for r in store.query(
        "SELECT heliostat_id, MAX(id) FROM heliostat_runs GROUP BY heliostat_id")}
    return Archive(campaigns, measurements, pairs, models, latest_run)


def fingerprint(path: str | Path) -> str:
    """SHA-256 over the database file and its write-ahead log (when there is one): what a
    resumed reprocessing checks it still reads."""
    h = hashlib.sha256()
    for p in (Path(path), Path(f"{path}-wal")):
        if p.is_file():
            with p.open("rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
    return h.hexdigest()
