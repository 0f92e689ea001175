"""The model update after a run: the tracking-model fit over every measurement of a heliostat
(earlier nights included), each weighted by its age, its joint references drifting from night
to night as a random walk (:mod:`controller.geometry.model.drift`)."""

from __future__ import annotations

import functools
import math
from datetime import datetime

import numpy as np

from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.config import ModelSettings
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.drift import RandomWalk
from controller.geometry.model.field_prior import FieldPrior
from controller.geometry.model.field_prior_io import read_prior
from controller.geometry.model.fit import NotIdentifiable, Sample, fit_model
from controller.geometry.model.tracking import TrackingModel, drift_sigma, prior_sigma


def fit_measurements(kin: HeliostatKinematics, measurements: list[MeasurementRecord],
                     settings: ModelSettings) -> ModelRecord | None:
    """:class:`ModelRecord` of the MAP fit to ``measurements`` (those with a centroid), with the
    noise and prior σ of ``settings`` (:class:`controller.config.ModelSettings`); None when no
    measurement has a centroid or the data identify no term."""
    used = [m for m in measurements if m.centroid_enu is not None]
    if not used:
        return None
    stamps = [m.measured_utc for m in used]
    weights = age_weights(stamps, settings.age_halflife_days)
    samples = [Sample(np.asarray(m.source_dir, float), m.az_steps, m.el_steps,
                      np.asarray(m.centroid_enu, float), float(w),
                      None if m.source_pos_enu is None else np.asarray(m.source_pos_enu, float), days_utc(s))
               for m, w, s in zip(used, weights, stamps, strict=True)]
    # The references walk by σ per √day; a night is a session (no gap of NIGHT_GAP_S within it).
    walk = RandomWalk(drift_sigma(settings.prior_sigma), gap_days=NIGHT_GAP_S / 86400.0)
    prior = model_prior(settings)
    try:
        fit = fit_model(kin, samples, noise_mrad=settings.noise_mrad, prior=TrackingModel(prior.mean),
                        prior_sigma=prior.sigma, drift=walk)
    except NotIdentifiable:
        return None
    detail = {"covariance_si": fit.covariance.tolist(), "identified": fit.identified_terms(),
              "noise_scale": fit.noise_scale, "converged": fit.converged}
    return ModelRecord(fit.model.to_dict(), fit.sigma_dict(), float(fit.residual_mrad_rms), len(samples),
                       detail)


def model_prior(settings: ModelSettings, source: str = "") -> FieldPrior:
    """Prior mean and 1-σ (SI) of every tracking-model term from ``calibration.model``: the
    field's prior (``field_prior``, read once per file) or the documented one, with the σ of
    the terms ``prior_sigma`` lists replaced. InputError naming ``source`` (the config file)
    and an unknown term key, or the prior file and its key."""
    base = _field_prior(settings.field_prior) if settings.field_prior else None
    sigma = prior_sigma(settings.prior_sigma, f"{source}: calibration.model.prior_sigma" if source
                        else "calibration.model.prior_sigma", base=None if base is None else base.sigma)
    mean = np.zeros(len(sigma)) if base is None else base.mean
    return FieldPrior(mean, sigma, np.zeros(len(sigma), int) if base is None else base.count)


@functools.lru_cache(maxsize=8)
def _field_prior(path: str) -> FieldPrior:
    return read_prior(path)


def unexplained_sigma_m(model: ModelRecord | None, noise_mrad: float, throw_m) -> float:
    """1-σ (m) of a beam's position that ``model``'s covariance does not hold, ``throw_m`` (m, a
    distance or the vector from the heliostat) away: its fit's residual RMS r beyond the stated
    noise n (effects the model lacks, or a measurement it could not follow), doubled by the
    reflection: 2·10⁻³ √max(0, r² − n²) · throw. A fit within its noise (nearly every one) adds
    nothing; 0 without a model or a residual."""
    r = None if model is None else model.residual_mrad
    if r is None or not math.isfinite(r):
        return 0.0
    return 2e-3 * math.sqrt(max(0.0, r * r - noise_mrad * noise_mrad)) * float(np.linalg.norm(throw_m))


NIGHT_GAP_S = 6 * 3600.0  # measurements further apart than this were taken on different nights


def _timestamp(s: str) -> float | None:
    try:
        return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
    except (AttributeError, ValueError):
        return None


def days_utc(stamp: str) -> float | None:
    """Days since 1970-01-01 UTC of an ISO 8601 stamp; None when it cannot be read."""
    t = _timestamp(stamp)
    return None if t is None else t / 86400.0


def age_weights(stamps: list[str], halflife_days: float) -> np.ndarray:
    """Fit weight of each measurement, w = 2^(−age / half-life), its age counted in days back
    from the newest of ``stamps`` (ISO 8601 UTC): the heliostat drifts, so old measurements
    tell less about it now. An unreadable stamp weighs 1."""
    t = [_timestamp(s) for s in stamps]
    known = [v for v in t if v is not None]
    if not known:
        return np.ones(len(stamps))
    newest = max(known)
    return np.array([1.0 if v is None else 0.5 ** ((newest - v) / 86400.0 / halflife_days) for v in t])
