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

from controller.calibration.cycle.pointing import model_covariance, steps_to_aim
from controller.calibration.night.workers import map_chunks
from controller.calibration.records import ModelRecord
from controller.config import Heliostat, Site
from controller.errors import LimitError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.fit import predicted_error
from controller.geometry.sun import solar_position
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


DRAWS = 100  # covariance draws per heliostat
EXACT_MAGNITUDES = 2_000_000  # up to this many pooled magnitudes the p95 is taken over all of them
# Beyond, each heliostat's magnitudes go into a histogram of log-spaced bins (0.35 % apart from
# 10⁻³ to 10³ mrad) and the p95 is interpolated in it: memory stays bounded at 10,000
# heliostats (75 M draws) and the percentile is within a bin's width.
HIST_EDGES = np.geomspace(1e-3, 1e3, 4001)


def predicted_daytime(cfg, models: dict[str, ModelRecord | None], path: SunPath | None = None, *,
                      workers: int | None = None) -> PredictedDaytime:
    """:class:`PredictedDaytime` of the heliostats in ``models`` at the calibration target's
    centre over ``path`` (default: :func:`sun_path` of the site); a large field in ``workers``
    processes (:mod:`controller.calibration.night.workers`)."""
    path = path or sun_path(cfg.site)
    exact = len(models) * DRAWS * len(path.directions) <= EXACT_MAGNITUDES
    parts = map_chunks(_daytime_chunk, list(models.items()), setup=_daytime_setup,
                       setup_args=(cfg, path.directions, exact), workers=workers)
    per = {hid: rms for part in parts for hid, rms in part[0].items()}
    sum_sq = sum(part[1] for part in parts)
    count = sum(part[2] for part in parts)
    if not count:
        return PredictedDaytime(float("nan"), float("nan"), per)
    if exact:
        return PredictedDaytime(float(np.sqrt(sum_sq / count)),
                                float(np.percentile(np.concatenate([part[3] for part in parts]), 95)), per)
    return PredictedDaytime(float(np.sqrt(sum_sq / count)), _percentile(sum(part[3] for part in parts), 95.0),
                            per)


def _percentile(hist: np.ndarray, q: float) -> float:
    """The q-th percentile of the magnitudes counted in ``hist`` over :data:`HIST_EDGES`
    (linear inside the bin it falls in)."""
    cum = np.cumsum(hist)
    goal = q / 100.0 * cum[-1]
    k = int(np.searchsorted(cum, goal))
    below = cum[k - 1] if k else 0.0
    frac = (goal - below) / max(hist[k], 1)
    return float(HIST_EDGES[k] + frac * (HIST_EDGES[k + 1] - HIST_EDGES[k]))


def _daytime_setup(cfg, directions: np.ndarray, exact: bool):
    return cfg, directions, exact


def _daytime_chunk(ctx, tasks: list) -> list[tuple]:
    """(per-heliostat RMS, Σ magnitude², count, magnitudes or their histogram) of a chunk."""
    cfg, directions, exact = ctx
    target = np.asarray(cfg.target().center_enu_m, float)
    per, sum_sq, count, pooled = {}, 0.0, 0, []
    hist = np.zeros(len(HIST_EDGES) - 1, np.int64)
    for hid, rec in tasks:
        model, cov = model_covariance(rec, cfg.calibration.model)
        kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
        pe = predicted_error(kin, model, cov, directions, target, draws=DRAWS)
        per[hid] = pe.rms
        mags = pe.draws_mrad.ravel()
        sum_sq += float(np.sum(mags**2))
        count += mags.size
        if exact:
            pooled.append(mags)
        else:
            hist += np.histogram(np.clip(mags, HIST_EDGES[0], HIST_EDGES[-1]), HIST_EDGES)[0]
    return [(per, sum_sq, count, np.concatenate(pooled) if exact and pooled else
             (np.empty(0) if exact else hist))]


class DaytimeTally:
    """The field's predicted daytime RMS kept up to date as models change: each heliostat's
    Σ magnitude² and count over its covariance draws (as :func:`predicted_daytime` pools them),
    recomputed only for the heliostats :meth:`update` is given — a night's pass refits a few
    hundred models of a field of thousands."""

    def __init__(self, cfg, path: SunPath) -> None:
        self.ctx = (cfg, path.directions, False)
        self.sums: dict[str, tuple[float, int]] = {}

    def update(self, models: dict[str, ModelRecord | None]) -> None:
        cfg, directions, _ = self.ctx
        target = np.asarray(cfg.target().center_enu_m, float)
        for hid, rec in models.items():
            model, cov = model_covariance(rec, cfg.calibration.model)
            pe = predicted_error(HeliostatKinematics.from_config(cfg.heliostat(hid)), model, cov, directions,
                                 target, draws=DRAWS)
            self.sums[hid] = (float(np.sum(pe.draws_mrad**2)), pe.draws_mrad.size)

    @property
    def rms(self) -> float:
        """Field RMS, mrad, of :func:`predicted_daytime` over the heliostats updated so far."""
        count = sum(c for _, c in self.sums.values())
        return float(np.sqrt(sum(s for s, _ in self.sums.values()) / count)) if count else float("nan")
