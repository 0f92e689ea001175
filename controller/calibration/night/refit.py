"""Every heliostat's tracking model refitted on all its measurements, the field at once.

A night's runs refit their heliostat's model as they go (:mod:`controller.calibration.cycle.model_update`).
Refitting the whole field is needed when what the fit depends on changes for every heliostat
at once — the fit settings of ``calibration.model`` (noise, prior σ, age half-life, drift) —
or to rebuild the models from the records. Each heliostat's fit depends on its own
measurements only, so the field is shared over a pool of processes
(:mod:`controller.calibration.night.workers`), with the same models as one at a time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from controller.calibration.cycle.model_update import fit_measurements
from controller.calibration.night.workers import map_chunks
from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.config import ModelSettings, PlantConfig
from controller.geometry.kinematics import HeliostatKinematics


@dataclass
class Refit:
    """The refitted models by heliostat (None: no measurement with a centroid, or nothing
    identified) and the wall seconds it took."""

    models: dict[str, ModelRecord | None]
    seconds: float


def refit_models(cfg: PlantConfig, history: dict[str, list[MeasurementRecord]], *,
                 workers: int | None = None) -> Refit:
    """The model of each heliostat of ``history`` (id -> its measurements, every night) fitted
    with ``calibration.model`` (:func:`controller.calibration.cycle.model_update.fit_measurements`),
    in ``workers`` processes (None: one per core for a large field)."""
    t0 = time.perf_counter()
    tasks = list(history.items())
    fits = map_chunks(_fit_chunk, tasks, setup=_setup, setup_args=(cfg,), workers=workers)
    return Refit({hid: m for (hid, _), m in zip(tasks, fits, strict=True)}, time.perf_counter() - t0)


def _setup(cfg: PlantConfig) -> tuple[PlantConfig, ModelSettings]:
    return cfg, cfg.calibration.model


def _fit_chunk(ctx: tuple[PlantConfig, ModelSettings], tasks: list) -> list[ModelRecord | None]:
    cfg, settings = ctx
    return [fit_measurements(HeliostatKinematics.from_config(cfg.heliostat(hid)), ms, settings)
            for hid, ms in tasks]
