"""The tracking table: for each heliostat and instant of one day, the sun's position, the axis
steps that put the sun's reflection on the calibration target's centre with the heliostat's
latest model, and the error its model's uncertainty predicts there.

The steps are those of ``heliocal aim --time`` (the same solar position, direction and
:func:`controller.calibration.cycle.pointing.steps_to_aim`). The day is the
site's mean solar day: from its local mean midnight, UTC − longitude/15 h rounded to the
minute, every ``step`` minutes for 24 h; a row is written while the sun is up and the pose is
within the soft limits. ``predicted_error_mrad`` is the reflected beam's RMS error that the
model's covariance leaves at that sun position (linearised: √tr(A Σ Aᵀ), A the beam's
sensitivity to the model terms, :func:`controller.geometry.design.beam_jacobians`).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from pathlib import Path

import numpy as np

from controller.calibration.cycle.pointing import model_covariance, steps_to_aim
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig, Site
from controller.errors import LimitError
from controller.geometry.design import beam_jacobians
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.sun import solar_position
from controller.geometry.vectors import azel_to_vector
from controller.io.images import write_atomic

COLUMNS = ("heliostat", "time_utc", "sun_azimuth_deg", "sun_elevation_deg", "az_steps", "el_steps",
           "predicted_error_mrad")


@dataclass(frozen=True)
class SunAt:
    """The sun at one instant: UTC time, azimuth (clockwise from north) and elevation, degrees."""

    time: datetime
    azimuth_deg: float
    elevation_deg: float


def day_instants(site: Site, day: date, step_min: float) -> list[datetime]:
    """Every ``step_min`` minutes of ``day``'s mean solar day at ``site`` (module docstring)."""
    midnight = datetime(day.year, day.month, day.day, tzinfo=UTC)
    start = midnight - timedelta(minutes=round(site.longitude_deg / 15.0 * 60.0))
    n = math.ceil(24 * 60 / step_min)
    return [start + timedelta(minutes=k * step_min) for k in range(n)]


def sun_up(site: Site, instants: list[datetime]) -> list[SunAt]:
    """The solar position (NREL SPA) at each instant, only those with the sun above the
    horizon. Computed for all instants at once: elementwise the same as ``heliocal aim``'s one
    instant (tests/plant/test_tracking_table.py checks the steps against it), 60× faster."""
    pos = solar_position(instants, site.latitude_deg, site.longitude_deg, site.elevation_m,
                         site.pressure_mbar, site.temperature_c, site.delta_t_s)
    return [SunAt(t, float(az) % 360.0, float(el))
            for t, az, el in zip(instants, pos.azimuth_deg, pos.elevation_deg, strict=True) if el > 0]


def heliostat_rows(cfg: PlantConfig, hid: str, model: ModelRecord | None,
                   suns: list[SunAt]) -> Iterator[dict]:
    """The table's rows of heliostat ``hid`` (``model``: its latest fitted model)."""
    kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
    aim = np.asarray(cfg.target().center_enu_m, float)
    tracking, cov = model_covariance(model, cfg.calibration.model)
    for sun in suns:
        s = azel_to_vector(sun.azimuth_deg, sun.elevation_deg)
        try:
            az, el = steps_to_aim(kin, model, s, aim)
        except (LimitError, ValueError):
            continue  # out of the soft limits at this sun position: not tracked then
        a = beam_jacobians(kin, tracking, np.asarray(s, float)[None, :], aim)
        err = 1e3 * math.sqrt(float(np.einsum("kip,pq,kiq->", a, cov, a))) if len(a) else float("nan")
        yield {"heliostat": hid, "time_utc": sun.time.isoformat(),
               "sun_azimuth_deg": f"{sun.azimuth_deg:.6f}", "sun_elevation_deg": f"{sun.elevation_deg:.6f}",
               "az_steps": int(az), "el_steps": int(el),
               "predicted_error_mrad": "" if math.isnan(err) else f"{err:.4f}"}


def write_tracking_table(path: str | Path, cfg: PlantConfig, models: dict[str, ModelRecord], day: date,
                         step_min: float) -> int:
    """Write the table of the heliostats of ``models`` (in that order) to ``path`` (CSV,
    :data:`COLUMNS`), atomically; returns the number of rows."""
    suns = sun_up(cfg.site, day_instants(cfg.site, day, step_min))
    count = 0

    def write(tmp: Path) -> None:
        nonlocal count
        with tmp.open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, COLUMNS)
            w.writeheader()
            for hid, model in models.items():
                for row in heliostat_rows(cfg, hid, model, suns):
                    w.writerow(row)
                    count += 1
    write_atomic(path, write)
    return count
