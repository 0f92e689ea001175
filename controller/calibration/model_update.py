"""The model update after a run: the tracking-model fit over every measurement of a heliostat
(earlier nights included), each weighted by its age and referred to its night's drift epoch."""

from __future__ import annotations

import bisect
import math
from datetime import datetime

import numpy as np

from controller.calibration.records import MeasurementRecord, ModelRecord
from controller.config import ModelSettings
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import NotIdentifiable, Sample, fit_model
from controller.geometry.tracking_model import drift_sigma, prior_sigma


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
    epochs, days = night_epochs(stamps)
    samples = [Sample(np.asarray(m.source_dir, float), m.az_steps, m.el_steps,
                      np.asarray(m.centroid_enu, float), float(w),
                      None if m.source_pos_enu is None else np.asarray(m.source_pos_enu, float), int(e))
               for m, w, e in zip(used, weights, epochs, strict=True)]
    drift = drift_sigma(settings.prior_sigma)
    # A random walk: the references of a night d days before the newest are off by σ √d.
    epoch_sigma = {e: drift * math.sqrt(d) for e, d in days.items() if e > 0} if drift > 0 else None
    try:
        fit = fit_model(kin, samples, noise_mrad=settings.noise_mrad, prior_sigma=model_prior(settings),
                        epoch_sigma=epoch_sigma)
    except NotIdentifiable:
        return None
    detail = {"covariance_si": fit.covariance.tolist(), "identified": fit.identified_terms(),
              "noise_scale": fit.noise_scale, "converged": fit.converged}
    return ModelRecord(fit.model.to_dict(), fit.sigma_dict(), float(fit.residual_mrad_rms), len(samples),
                       detail)


def model_prior(settings: ModelSettings, source: str = "") -> np.ndarray:
    """Prior 1-σ (SI) of every tracking-model term from ``calibration.model``; InputError
    naming ``source`` (the config file) and an unknown term key."""
    return prior_sigma(settings.prior_sigma, f"{source}: calibration.model.prior_sigma" if source
                       else "calibration.model.prior_sigma")


NIGHT_GAP_S = 6 * 3600.0  # measurements further apart than this were taken on different nights


def night_epochs(stamps: list[str]) -> tuple[list[int], dict[int, float]]:
    """The night of each measurement (ISO 8601 UTC ``stamps``), counted back from the newest
    (0), nights being runs of measurements without a gap of :data:`NIGHT_GAP_S`; and per night
    its distance in days from the newest (at least 1 for an earlier night). An unreadable
    stamp belongs to the newest night."""
    t = [_timestamp(s) for s in stamps]
    known = sorted({v for v in t if v is not None})
    if not known:
        return [0] * len(stamps), {0: 0.0}
    starts = [known[0]] + [b for a, b in zip(known, known[1:], strict=False) if b - a > NIGHT_GAP_S]
    last = len(starts) - 1
    days = {last - i: 0.0 if i == last else max(1.0, round((starts[-1] - st) / 86400.0))
            for i, st in enumerate(starts)}
    epoch = [0 if v is None else last - (bisect.bisect_right(starts, v) - 1) for v in t]
    return epoch, days


def _timestamp(s: str) -> float | None:
    try:
        return datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
    except (AttributeError, ValueError):
        return None


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
