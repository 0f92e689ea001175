"""Fit of the tracking model (:mod:`controller.geometry.model.tracking`) by identifiability.

Maximum a posteriori least squares. Each measurement k (source direction s_k, commanded
steps, measured spot) gives the measured normal m_k(p), the bisector of s_k and the direction
from the model's mirror centre to the spot (for a lamp, s_k too is taken from that centre);
the model gives n_k(p). With t₁, t₂ a tangent basis at m_k, σ_n the noise of a measured
normal (rad) and w_k a weight (robust or age), minimise

    Σ_k w_k [(t₁·(n_k − m_k))² + (t₂·(n_k − m_k))²] / σ_n²  +  Σ_i ((p_i − p₀,i) / σ₀,i)²   (1)

— a Gaussian prior N(p₀, σ₀²) on every term (the documented defaults, or a field's prior
learned from its heliostats, :mod:`controller.geometry.model.field_prior`), so the fit is defined
for any data and the data move only the combinations they observe. At the optimum, with J
the Jacobian of the whitened residuals of (1),

    Σ = s² (JᵀJ + P)⁻¹,   s² = χ²_data / (2m − p_eff),   p_eff = Σ_i (1 − Σ_ii/σ₀,i²)    (2)

(P the prior precision; s² = max(1, χ²/dof) once the residuals have at least 10 degrees of
freedom, else 1: the stated noise is a floor, and residuals larger than it — noise or effects
the model lacks — widen the uncertainty). A term is *identified* when the data's information
alone (Eq. 2 with s = 1) shrinks its σ below half its prior σ; the others stay at the prior
and are reported as such. The fit refuses when no term is identified.

Drift: the joint references of a heliostat wander in time. Given a
:class:`~controller.geometry.model.drift.RandomWalk` and measurement times, a measurement of
session e sees the model with its two reference offsets moved by d_e, the sessions' d_e a
random walk ending at 0 in the newest session (:mod:`controller.geometry.model.drift`, Eq. 1):

    n_k(p, d) = n(p + D d_e(k)),   D: the rows of ``az_offset`` and ``el_offset``            (3)

Every earlier session's d_e is fitted beside p (nuisance terms): all sessions' data still
determine the other terms, while the reference offsets — and every prediction — are those of
the newest session. Σ and the identified terms of (2) are those of p alone (the marginal).

Outliers: iteratively reweighted least squares on each measurement's whitened residual norm
r_k: Huber weights w_k = min(1, c / r_k) for the first :data:`WARMUP` steps, then the
redescending weight w_k = min(1, (c / r_k)²) (loss r²/2 inside c, c²(½ + ln(r/c)) beyond: a
record whose motor position was not where the heliostat was — real records 30–50 mrad off —
stops pulling at all), c = 3. The steps start from :mod:`controller.geometry.model.start`
(the joint references moved by the median miss; an actuator whose properties leave its
triangle re-seated), and a step that would leave an actuator's triangle is halved.

Predicted pointing error: for a set of aims (sun direction, aim point), the reflected beam
r = 2(s·n)n − s at the model's steps moves by δr ≈ J_r δp for a parameter error δp ~ N(0, Σ);
its RMS over the aims is sqrt(mean_k tr(J_r,k Σ J_r,kᵀ)) and the p95 is taken over draws.

References
----------
.. [1] A. Tarantola, "Inverse Problem Theory", SIAM 2005, Sec. 3.2: least squares with a
   Gaussian prior; posterior covariance (GᵀC_d⁻¹G + C_p⁻¹)⁻¹.
.. [2] P. J. Huber, "Robust Statistics", Wiley 1981: Huber weights, IRLS; Sec. 4.8:
   redescending M-estimators.
.. [3] M. Pargmann et al., ARTIST, Nature Communications 15, 6997, 2024: actuator initial
   stroke and angle as calibration parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.aiming import angle_mrad
from controller.geometry.design import beam_jacobians, tangents_batch
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.drift import DRIFTING, RandomWalk, Sessions, chain_precision, sessions
from controller.geometry.model.start import Start, implied_normals, start
from controller.geometry.model.tracking import (
    NAMES,
    PRIOR_SIGMA_SI,
    TERMS,
    TrackingModel,
    implied_normal,
    model_normal,
)
from controller.geometry.pose_batch import normal_and_center

_OFFSETS = np.array([NAMES.index(n) for n in DRIFTING])
HUBER_C = 3.0
WARMUP = 3
MAX_STEPS = 20
IDENTIFIED_RATIO = 0.5
MIN_DOF_FOR_NOISE = 10.0
_JAC_STEP = 1e-4  # whitened units: far inside the linear range of every term


class NotIdentifiable(InputError):
    """The measurements determine no term of the model: they cannot support a fit."""


@dataclass(frozen=True, eq=False)  # numpy fields
class Sample:
    """One pointing measurement: unit ENU ``source_dir`` (towards the source), commanded
    motor steps, measured beam centroid ``spot_enu`` (m ENU), a ``weight`` (1: full; less
    for an old measurement), a lamp's position ``source_pos`` (m ENU; None: the sun, at
    infinity) and its time ``time_days`` (days, UTC; None: unknown, the newest session)."""

    source_dir: np.ndarray
    az_steps: float
    el_steps: float
    spot_enu: np.ndarray
    weight: float = 1.0
    source_pos: np.ndarray | None = None
    time_days: float | None = None


@dataclass(frozen=True, eq=False)  # numpy fields
class ModelFit:
    """Result of :func:`fit_model`.

    ``model``: fitted values (the newest session's); ``sigma``: 1-σ per term (SI);
    ``covariance`` (SI²); ``identified``: per term, whether the data determined it (σ < ½
    prior σ); ``residual_mrad`` per sample (angle between model and measured normals, at the
    sample's session) and its RMS before/after (before: the prior's model, NaN where its
    kinematics cannot be evaluated); ``weights``: final robust weights; ``noise_scale`` s of
    Eq. (2); ``condition``: condition number of the data Jacobian over the identified terms
    (prior-whitened); ``converged``: whether the steps and robust weights settled within
    :data:`MAX_STEPS`; ``drift_mrad`` (E, 2): each session's reference offsets (az, el) from
    the newest session's, with ``session_times`` (E,) days (the last measurement of each);
    ``notes``: what the fit did that its caller should say (a re-seated actuator)."""

    model: TrackingModel
    sigma: np.ndarray
    covariance: np.ndarray
    identified: np.ndarray
    residual_mrad: np.ndarray
    residual_mrad_rms: float
    initial_residual_mrad_rms: float
    weights: np.ndarray
    noise_scale: float
    condition: float
    converged: bool = True
    drift_mrad: np.ndarray | None = None
    session_times: np.ndarray | None = None
    notes: tuple[str, ...] = ()

    def sigma_dict(self) -> dict[str, float]:
        return {t.key: 1e3 * float(s) for t, s in zip(TERMS, self.sigma, strict=True)}

    def identified_terms(self) -> list[str]:
        return [n for n, ok in zip(NAMES, self.identified, strict=True) if ok]


def measured_normal(kin: HeliostatKinematics, model: TrackingModel, s: Sample) -> np.ndarray:
    """The normal a sample implies: bisector of the source direction and the direction from the
    mirror centre (with ``model``, at the commanded steps) to the measured spot; for a lamp the
    source direction is taken from that mirror centre too."""
    return implied_normal(kin, model, s.az_steps, s.el_steps, s.source_dir, s.spot_enu, s.source_pos)


def normal_residual_mrad(kin: HeliostatKinematics, model: TrackingModel, s: Sample) -> float:
    """Angle between the model's normal at the sample's steps and the normal the sample
    implies with that model (:func:`measured_normal`), mrad."""
    return float(angle_mrad(model_normal(kin, model, s.az_steps, s.el_steps), measured_normal(kin, model, s)))


def _check(samples: Sequence[Sample], noise_mrad: float) -> None:
    if not samples:
        raise InputError("model fit: no measurements")
    if not (np.isfinite(noise_mrad) and noise_mrad > 0):
        raise InputError(f"model fit: noise must be a positive number of mrad, got {noise_mrad}")
    for i, s in enumerate(samples):
        vals = np.concatenate([np.ravel(s.source_dir), [s.az_steps, s.el_steps, s.weight],
                               np.ravel(s.spot_enu)])
        if not np.all(np.isfinite(vals)) or s.weight <= 0:
            raise InputError(f"model fit: measurement {i + 1} has a non-finite value or weight <= 0")
        if s.time_days is not None and not np.isfinite(s.time_days):
            raise InputError(f"model fit: measurement {i + 1} has a non-finite time")


def _robust(norms: np.ndarray, redescending: bool) -> np.ndarray:
    """Weights of the module docstring for whitened residual norms ``norms``."""
    ratio = HUBER_C / np.maximum(norms, 1e-12)
    return np.minimum(1.0, ratio**2 if redescending else ratio)


@dataclass(frozen=True, eq=False)  # numpy fields
class _Data:
    """The samples as arrays: ``steps`` (S, 2), ``spots`` (S, 3), ``lamps`` (S, 3; NaN rows:
    the sun), unit ``src`` (S, 3), age weights ``age_w`` (S,)."""

    steps: np.ndarray
    spots: np.ndarray
    lamps: np.ndarray
    src: np.ndarray
    age_w: np.ndarray

    @classmethod
    def of(cls, samples: Sequence[Sample]) -> _Data:
        src = np.array([np.ravel(s.source_dir) for s in samples], float)
        return cls(np.array([[s.az_steps, s.el_steps] for s in samples], float),
                   np.array([np.ravel(s.spot_enu) for s in samples], float),
                   np.array([np.ravel(s.source_pos) if s.source_pos is not None else np.full(3, np.nan)
                             for s in samples], float),
                   src / np.linalg.norm(src, axis=1, keepdims=True), np.array([s.weight for s in samples]))


class _Problem:
    """Eq. (1) and (3) for one set of samples, in whitened coordinates x = (terms, sessions):
    p = p₀ + σ₀ x_terms, d_e = u_e y_e (model_drift)."""

    def __init__(self, kin: HeliostatKinematics, data: _Data, p0: np.ndarray, s0: np.ndarray,
                 sess: Sessions | None, noise_rad: float):
        self.kin, self.p0, self.s0, self.sess, self.noise = kin, p0, s0, sess, noise_rad
        self.npar = len(p0)
        self.steps, self.spots, self.lamps = data.steps, data.spots, data.lamps
        self.src, self.age_w = data.src, data.age_w
        m = 0 if sess is None else sess.count - 1
        self.ndrift = len(DRIFTING) * m
        # Session of each sample as a column block of y (the newest session has none).
        self.member = np.zeros((len(self.steps), max(m, 1)))
        if m:
            newest = sess.index == m
            self.member[np.flatnonzero(~newest), sess.index[~newest]] = 1.0
        precision = np.zeros((self.npar + self.ndrift,) * 2)
        precision[:self.npar, :self.npar] = np.eye(self.npar)
        if m:
            precision[self.npar:, self.npar:] = chain_precision(sess)
        self.precision = precision

    def values(self, x: np.ndarray) -> np.ndarray:
        return self.p0 + self.s0 * x[:self.npar]

    def sample_values(self, terms: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Per-sample model values (B, S, n) for term rows ``terms`` (B, n) and the sessions of x."""
        out = np.repeat(terms[:, None, :], len(self.steps), axis=1)
        if self.ndrift:
            y = x[self.npar:].reshape(-1, len(DRIFTING)) * self.sess.scale[:, None]
            out[:, :, _OFFSETS] += (self.member @ y)[None]
        return out

    def residuals(self, terms: np.ndarray, x: np.ndarray, set_bases: bool = False) -> np.ndarray:
        """Whitened data residuals (B, 2S) at each row of ``terms`` (B, n), sessions of x. The
        first row's normals and implied normals (S, 3) are kept as ``first``; with ``set_bases``
        the tangent bases are taken at the first row's implied normals first."""
        n, c = normal_and_center(self.kin, self.sample_values(terms, x), self.steps)
        implied = implied_normals(c, self.src, self.spots, self.lamps)
        if set_bases:
            # The tangent bases stay those at the start: the measured normals move only through
            # the mirror centre (position terms), by far less than the bases' validity.
            self.bases = tangents_batch(implied[0])
        self.first = (n[0], implied[0])
        return np.einsum("sij,bsj->bsi", self.bases, n - implied).reshape(len(terms), -1) / self.noise

    def linearise(self, x: np.ndarray, set_bases: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(residuals at x, their Jacobian (2S, L)): forward differences over the terms; a
        session's columns are its samples' reference-offset columns times u_e (Eq. 3). With
        ``set_bases``, the residuals' tangent bases are taken at x first (the fit's start)."""
        base = self.values(x)
        rows = np.vstack([base, base + np.diag(self.s0 * _JAC_STEP)])
        r = self.residuals(rows, x, set_bases)
        jt = ((r[1:] - r[0]) / _JAC_STEP).T
        if not self.ndrift:
            return r[0], jt
        k = len(DRIFTING)
        off = jt[:, _OFFSETS] / self.s0[_OFFSETS]  # per rad of offset
        member2 = np.repeat(self.member, 2, axis=0)  # rows are (sample, tangent) pairs
        jd = (member2[:, :, None] * off[:, None, :] * self.sess.scale[None, :, None]).reshape(len(r[0]), -1)
        return r[0], np.hstack([jt, jd[:, :k * (self.sess.count - 1)]])


def fit_model(kin: HeliostatKinematics, samples: Sequence[Sample], *, noise_mrad: float = 0.3,
              prior: TrackingModel | None = None, prior_sigma: np.ndarray | None = None,
              robust: bool = True, drift: RandomWalk | None = None) -> ModelFit:
    """MAP fit of Eq. (1); Σ of Eq. (2). ``prior`` (default zero) is p₀; ``prior_sigma`` (SI,
    default :data:`TERMS`' σ) may be narrowed (e.g. the posterior of a previous night) or be a
    field's. ``drift``: the references' random walk over the samples' times (Eq. 3); None or
    inactive: one set of references for all samples.

    Raises InputError when there are no samples, a sample is not finite, or the samples
    identify no term (they cannot support a fit)."""
    _check(samples, noise_mrad)
    p0 = (prior or TrackingModel.zero()).values
    s0 = PRIOR_SIGMA_SI if prior_sigma is None else np.asarray(prior_sigma, float)
    sess = sessions([s.time_days for s in samples], drift) if drift is not None and drift.active() else None
    if sess is not None and sess.count < 2:
        sess = None
    data = _Data.of(samples)
    st = start(kin, p0, s0, data.steps, data.src, data.spots, data.lamps)
    pb = _Problem(kin, data, st.prior, st.sigma, sess, noise_mrad * 1e-3)
    x = np.zeros(pb.npar + pb.ndrift)
    x[:pb.npar] = (st.values - st.prior) / st.sigma
    weights = np.ones(len(samples))
    converged = False
    r, jac = pb.linearise(x, set_bases=True)
    for it in range(MAX_STEPS):
        w = np.repeat(np.sqrt(weights * pb.age_w), 2)
        jd = w[:, None] * jac
        dx = -np.linalg.solve(jd.T @ jd + pb.precision, jd.T @ (w * r) + pb.precision @ x)
        # The next step's residuals and Jacobian, taken where this one lands (one evaluation
        # of the model for both); a step that leaves an actuator's triangle is halved.
        for _ in range(20):
            r, jac = pb.linearise(x + dx)
            if np.all(np.isfinite(r)):
                break
            dx = dx / 2.0
        x = x + dx
        norms = np.sqrt(pb.age_w) * np.linalg.norm(r.reshape(-1, 2), axis=1)
        new = _robust(norms, redescending=it >= WARMUP) if robust else weights
        settled = np.max(np.abs(dx)) < 1e-6 and np.allclose(new, weights, atol=1e-3)
        if settled and (it >= WARMUP or not robust):
            converged = True
            break
        weights = new
    return _result(pb, samples, x, weights, converged, st, p0, (r, jac))


def _result(pb: _Problem, samples: Sequence[Sample], x: np.ndarray, weights: np.ndarray, converged: bool,
            st: Start, p0: np.ndarray, linear: tuple[np.ndarray, np.ndarray]) -> ModelFit:
    """ModelFit at the optimum x: Σ and identification of Eq. (2), residuals per sample;
    ``linear``: (residuals, Jacobian) at x, the last evaluation of ``pb`` (its ``first`` row:
    the normals at x); ``st``: the start, whose normals at its prior are those at ``p0`` when
    no actuator was repaired."""
    npar = pb.npar
    w = np.repeat(np.sqrt(weights * pb.age_w), 2)
    r, jac = linear
    jd = w[:, None] * jac
    post_x = np.linalg.inv(jd.T @ jd + pb.precision)
    ratio2 = np.clip(np.diag(post_x)[:npar], 0.0, 1.0)
    p_eff = float(np.sum(1.0 - ratio2))
    chi2 = float(np.sum((w * r) ** 2))
    dof = 2 * len(samples) - p_eff
    # The stated noise is a floor: residuals larger than it (noise or effects the model lacks)
    # widen the uncertainty once there are enough of them to tell; smaller ones never narrow it.
    s2 = max(1.0, chi2 / dof) if dof >= MIN_DOF_FOR_NOISE else 1.0
    cov = s2 * post_x[:npar, :npar] * np.outer(pb.s0, pb.s0)  # the terms' marginal (drift out)
    # Identified by the information the data carry (σ without s): a model that misfits real
    # records widens every σ, but the terms the data determine are still determined.
    identified = np.sqrt(ratio2) < IDENTIFIED_RATIO
    if not identified.any():
        raise NotIdentifiable(f"model fit: {len(samples)} measurement(s) identify no term of the model "
                              f"(every σ stays above {IDENTIFIED_RATIO:g}× its prior); "
                              "measure more geometries")
    sv = np.linalg.svd(jd[:, :npar][:, identified], compute_uv=False)
    values = pb.values(x)
    res = angle_mrad(*pb.first)
    if st.notes:  # the start's prior is a repaired p0: the initial residuals are p0's own
        n0, c0 = normal_and_center(pb.kin, np.repeat(p0[None], len(samples), axis=0), pb.steps)
        res0 = angle_mrad(n0, implied_normals(c0, pb.src, pb.spots, pb.lamps))
    else:
        res0 = angle_mrad(*st.at_prior)
    drift, times = None, None
    if pb.ndrift:
        y = x[npar:].reshape(-1, len(DRIFTING)) * pb.sess.scale[:, None]
        drift = 1e3 * np.vstack([y, np.zeros((1, len(DRIFTING)))])
        times = pb.sess.times
    rms0 = float(np.sqrt(np.mean(res0[np.isfinite(res0)] ** 2))) if np.isfinite(res0).any() else float("nan")
    return ModelFit(TrackingModel(values), np.sqrt(np.diag(cov)), cov, identified, res,
                    float(np.sqrt(np.mean(res**2))), rms0, weights, float(np.sqrt(s2)), float(sv[0] / sv[-1]),
                    converged, drift, times, st.notes)


@dataclass(frozen=True, eq=False)  # numpy field
class PredictedError:
    """Predicted reflected-beam error over a set of aims, mrad: ``rms``, ``p95``, the number
    of aims the heliostat could reach (``aims``), and ``draws_mrad`` (draws × aims), the error
    magnitudes of the covariance draws (to pool several heliostats)."""

    rms: float
    p95: float
    aims: int
    draws_mrad: np.ndarray

    def to_json(self) -> dict:
        return {"rms": self.rms, "p95": self.p95, "aims": self.aims}


def predicted_error(kin: HeliostatKinematics, model: TrackingModel, covariance: np.ndarray,
                    source_dirs: np.ndarray, aim_point, *, draws: int = 400, seed: int = 0) -> PredictedError:
    """Reflected-beam error (mrad) that the model's uncertainty ``covariance`` (SI²) leaves when
    the heliostat aims at ``aim_point`` (m ENU) from each of ``source_dirs`` (n, 3): the
    linearised propagation of the module docstring. Unreachable aims are skipped."""
    j = beam_jacobians(kin, model, source_dirs, aim_point)  # (k, 3, p)
    if not len(j):
        raise InputError("predicted error: the heliostat reaches none of the aims")
    var = np.einsum("kip,pq,kiq->k", j, covariance, j)
    rng = np.random.default_rng(seed)
    dp = rng.multivariate_normal(np.zeros(len(model.values)), covariance, size=draws, method="eigh")
    mags = np.linalg.norm(np.einsum("kip,dp->kdi", j, dp), axis=-1)
    return PredictedError(1e3 * float(np.sqrt(np.mean(var))), 1e3 * float(np.percentile(mags, 95)), len(j),
                          1e3 * mags.T)
