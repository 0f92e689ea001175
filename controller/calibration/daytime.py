"""Daytime tracking: what calibration is for. With a heliostat's fitted model, the motor steps
that put the sun's reflection on the target centre at any sun position — the geometries the
night never measured.

The evaluation sun path (:func:`sun_path`) is four days of a year — the March and September
equinoxes and the June and December solstices — every ``step_min`` minutes while the sun is
above ``min_elevation_deg``: the spread of sun positions a year of tracking sees.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np

from controller.calibration.pointing import steps_to_aim
from controller.calibration.records import ModelRecord
from controller.config import Heliostat, Site
from controller.errors import LimitError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import predicted_error
from controller.geometry.sun import solar_position
from controller.geometry.tracking_model import TERMS, TrackingModel, prior_sigma
from controller.geometry.vectors import azel_to_vector

EVALUATION_DAYS = ((3, 20), (6, 21), (9, 22), (12, 21))  # (month, day): equinoxes and solstices


@dataclass(frozen=True)
class SunPath:
    """Sun positions: UTC times (n,), azimuth (clockwise from north) and elevation in degrees
    (n,), and unit ENU directions towards the sun (n, 3)."""

    times: tuple[datetime, ...]
    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    directions: np.ndarray


def sun_path(site: Site, year: int = 2026, step_min: float = 30.0,
             min_elevation_deg: float = 15.0) -> SunPath:
    """The evaluation path at ``site`` (module docstring), from NREL SPA."""
    times = [datetime(year, m, d, tzinfo=UTC) + timedelta(minutes=k * step_min)
             for m, d in EVALUATION_DAYS for k in range(int(24 * 60 / step_min))]
    pos = solar_position(times, site.latitude_deg, site.longitude_deg, site.elevation_m, site.pressure_mbar,
                         site.temperature_c, site.delta_t_s)
    up = np.asarray(pos.elevation_deg) > min_elevation_deg
    az, el = np.asarray(pos.azimuth_deg)[up], np.asarray(pos.elevation_deg)[up]
    dirs = np.array([azel_to_vector(a, e) for a, e in zip(az, el, strict=True)]).reshape(-1, 3)
    return SunPath(tuple(t for t, keep in zip(times, up, strict=True) if keep), az, el, dirs)


def tracking_steps(heliostat: Heliostat, model: ModelRecord | None, sun_dirs: np.ndarray,
                   aim_point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps (n, 2) that aim ``heliostat`` at ``aim_point`` for each sun direction (n, 3) with
    ``model`` (None: nominal), and a mask (n,) of the sun positions it can reach."""
    kin = HeliostatKinematics.from_config(heliostat)
    steps = np.zeros((len(sun_dirs), 2), dtype=np.int64)
    ok = np.zeros(len(sun_dirs), dtype=bool)
    for i, s in enumerate(sun_dirs):
        try:
            steps[i] = steps_to_aim(kin, model, s, aim_point)
            ok[i] = True
        except (LimitError, ValueError):
            continue  # outside the soft limits at this sun position: not tracked then
    return steps, ok


@dataclass(frozen=True)
class PredictedDaytime:
    """Daytime error the models' own uncertainty predicts (mrad, reflected beam, open loop):
    field ``rms`` and ``p95`` over heliostats × sun positions × covariance draws, and each
    heliostat's RMS (``per_heliostat``)."""

    rms: float
    p95: float
    per_heliostat: dict[str, float]

    def to_json(self) -> dict:
        return {"rms": self.rms, "p95": self.p95}


def model_covariance(model: ModelRecord | None, prior: dict[str, float] | None = None) -> tuple[TrackingModel,
                                                                                                 np.ndarray]:
    """(model, covariance SI²) of a stored model; the nominal model with the prior covariance
    when there is none (or it predates covariances)."""
    cov = None if model is None else model.detail.get("covariance_si")
    if cov is None or len(cov) != len(TERMS):
        base = TrackingModel.zero() if model is None else TrackingModel.from_dict(model.params)
        return base, np.diag(prior_sigma(prior, "calibration.model.prior_sigma") ** 2)
    return TrackingModel.from_dict(model.params), np.asarray(cov, float)


def predicted_daytime(cfg, models: dict[str, ModelRecord | None],
                      path: SunPath | None = None) -> PredictedDaytime:
    """:class:`PredictedDaytime` of the heliostats in ``models`` at the calibration target's
    centre over ``path`` (default: :func:`sun_path` of the site)."""
    path = path or sun_path(cfg.site)
    target = np.asarray(cfg.target().center_enu_m, float)
    per, pooled = {}, []
    for hid, rec in models.items():
        model, cov = model_covariance(rec, cfg.calibration.model.prior_sigma)
        kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
        pe = predicted_error(kin, model, cov, path.directions, target, draws=100)
        per[hid] = pe.rms
        pooled.append(pe.draws_mrad.ravel())
    mags = np.concatenate(pooled) if pooled else np.empty(0)
    if not mags.size:
        return PredictedDaytime(float("nan"), float("nan"), per)
    return PredictedDaytime(float(np.sqrt(np.mean(mags**2))), float(np.percentile(mags, 95)), per)
