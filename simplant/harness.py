"""What only the simulator knows, kept beside the product's records, and the simulated
plant's error library.

The controller records what it measured (``controller.storage``); :class:`TruthRecorder`
observes the product's campaigns (:class:`controller.calibration.campaign.observers.CampaignObserver`)
and writes the plant's truth into its own table ``sim_truth`` of the same database file: per
recorded run, the injected error case and the true reflected-beam error at the first and the
last measurement. Reports written by the simulation commands read it back (:func:`read_truth`).
The simulated plant never runs a campaign or a night itself: ``controller.commands.simulated``
runs the product's on the simulated field.
"""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import numpy as np

from controller.calibration.campaign.observers import CampaignObserver
from controller.calibration.records import MeasurementRecord, RunRecord
from controller.config import PlantConfig
from controller.recognition.library import Library
from controller.reports.summary import ReferenceTruth
from simplant.plant import SimulatedPlant, load_config_data
from simplant.reference_set import write_reference_set

_SCHEMA = """
CREATE TABLE IF NOT EXISTS sim_truth (
    run_id INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL,
    heliostat_id TEXT NOT NULL,
    truth_label TEXT NOT NULL,
    true_error_before_mrad REAL,
    true_error_after_mrad REAL
)
"""


class TruthRecorder(CampaignObserver):
    """Reads the plant's true pointing error at every measurement and stores, per recorded
    run, the first and last one with the injected case (own connection, own transaction)."""

    def __init__(self, plant: SimulatedPlant, db_path: str | Path) -> None:
        self.plant = plant
        self.db_path = str(db_path)
        self._errors: dict[str, list[float]] = {}
        self._lock = threading.Lock()
        with sqlite3.connect(self.db_path) as db:
            db.execute(_SCHEMA)

    def measured(self, heliostat_id: str, measurement: MeasurementRecord) -> None:
        err = self.plant.true_error_mrad(heliostat_id)
        if measurement.centroid_enu is not None:  # whose spot it really was (several beams per target)
            self.plant.spot_truth.misassigned(heliostat_id, measurement.centroid_enu)
        with self._lock:
            self._errors.setdefault(heliostat_id, []).append(err)

    def run_recorded(self, campaign_id: int, run: RunRecord) -> None:
        with self._lock:
            errs = self._errors.pop(run.heliostat_id, [])
        with sqlite3.connect(self.db_path, timeout=10.0) as db:
            db.execute("INSERT OR REPLACE INTO sim_truth VALUES (?,?,?,?,?,?)",
                       (run.id, campaign_id, run.heliostat_id, self.plant.truth_label(run.heliostat_id),
                        errs[0] if errs else None, errs[-1] if errs else None))


def read_truth(db_path: str | Path, campaign_id: int) -> dict[str, ReferenceTruth]:
    """The simulated truth of every recorded run of a campaign (heliostat id -> truth)."""
    with sqlite3.connect(f"file:{db_path}?mode=ro", uri=True) as db:
        if db.execute("SELECT 1 FROM sqlite_master WHERE name='sim_truth'").fetchone() is None:
            return {}
        rows = db.execute("SELECT heliostat_id, truth_label, true_error_before_mrad, true_error_after_mrad "
                          "FROM sim_truth WHERE campaign_id=?", (campaign_id,)).fetchall()
    return {hid: ReferenceTruth(label, before, after) for hid, label, before, after in rows}


FIELD_FACTOR = 1.5


def widen_unknown_for_field(lib: Library, factor: float = FIELD_FACTOR) -> Library:
    """Raise each entry's ``unknown`` threshold to ``factor`` x the largest distance to the
    same case's entries from the other reference heliostats.

    The library's own calibration covers framing and noise of one view; across a field the
    same error looks different from every heliostat (distance, incidence angle), and the
    references measure exactly that spread. Thresholds are only ever raised."""
    x = lib.matrix() / lib.scale
    labels = np.array(lib.labels)
    for i, e in enumerate(lib.entries):
        same = (labels == e.label) & (np.arange(len(labels)) != i)
        if same.any():
            spread = float(np.max(np.linalg.norm(x[same] - x[i], axis=1)))
            e.unknown_distance = max(float(e.unknown_distance), factor * spread)
    return lib


def demo_library(cfg: PlantConfig, config_path: str, out: Path, ids: list[str], seed: int,
                 progress=None) -> Library:
    """The error library of a simulated run: the error set's cases rendered through the plant's
    own camera for three reference heliostats across the field (first, middle, last of the
    run), built once into ``out/library.yaml`` and then reused. ``progress(text)`` is told
    when the (slow) build starts."""
    from controller.recognition.library_io import build_library_from_manifest, load_library, save_library

    path = out / "library.yaml"
    if path.is_file():
        return load_library(path)
    refs = list(dict.fromkeys([ids[0], ids[len(ids) // 2], ids[-1]]))
    if progress is not None:
        progress(f"building the error library: 6 error-set cases x {len(refs)} reference heliostats ...")
    manifest = write_reference_set(load_config_data(config_path), out / "errorset", refs, seed=seed,
                                   source=str(config_path))
    lib = widen_unknown_for_field(build_library_from_manifest(manifest, kind="log-hu",
                                                              threshold=cfg.calibration.threshold))
    save_library(lib, path)
    return lib
