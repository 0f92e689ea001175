"""Fit of the tracking model (:mod:`controller.geometry.tracking_model`) by identifiability.

Maximum a posteriori least squares. Each measurement k (source direction s_k, commanded
steps, measured spot) gives the measured normal m_k(p), the bisector of s_k and the direction
from the model's mirror centre to the spot (for a lamp, s_k too is taken from that centre);
the model gives n_k(p). With t₁, t₂ a tangent basis at m_k, σ_n the noise of a measured
normal (rad) and w_k a weight (robust or age), minimise

    Σ_k w_k [(t₁·(n_k − m_k))² + (t₂·(n_k − m_k))²] / σ_n²  +  Σ_i ((p_i − p₀,i) / σ₀,i)²   (1)

— a Gaussian prior N(p₀, σ₀²) on every term, so the fit is defined for any data and the
data move only the combinations they observe. At the optimum, with J the Jacobian of the
whitened residuals of (1),

    Σ = s² (JᵀJ)⁻¹,   s² = χ²_data / (2m − p_eff),   p_eff = Σ_i (1 − Σ_ii/σ₀,i²)      (2)

(the posterior covariance; s² = max(1, χ²/dof) once the residuals have at least 10 degrees of
freedom, else 1: the stated noise is a floor, and residuals larger than it — noise or effects
the model lacks — widen the uncertainty). A term is
*identified* when the data shrink its σ below half its prior σ; the others stay at the
prior and are reported as such. The fit refuses when no term is identified.

Drift: the joint references of a heliostat wander from night to night (thermal drift). A
sample taken on an earlier night e (``Sample.epoch``, 0 = the newest night) sees the model
with its two reference offsets moved by d_e ~ N(0, σ_e² I₂), σ_e from ``epoch_sigma``:

    n_k(p, d) = n(p + D d_e(k)),   D: the rows of ``az_offset`` and ``el_offset``            (3)

and every earlier night's d_e is fitted beside p with that Gaussian prior (nuisance terms):
the data of all nights still determine the other terms, while the reference offsets are those
of the newest night. Σ and the identified terms of (2) are those of p alone (the marginal).

Outliers: iteratively reweighted least squares with Huber weights on each measurement's
whitened residual norm r_k, w_k = min(1, c / r_k), c = 3.

Predicted pointing error: for a set of aims (sun direction, aim point), the reflected beam
r = 2(s·n)n − s at the model's steps moves by δr ≈ J_r δp for a parameter error δp ~ N(0, Σ);
its RMS over the aims is sqrt(mean_k tr(J_r,k Σ J_r,kᵀ)) and the p95 is taken over draws.

References
----------
.. [1] A. Tarantola, "Inverse Problem Theory", SIAM 2005, Sec. 3.2: least squares with a
   Gaussian prior; posterior covariance (GᵀC_d⁻¹G + C_p⁻¹)⁻¹.
.. [2] P. J. Huber, "Robust Statistics", Wiley 1981: Huber weights, IRLS.
.. [3] M. Pargmann et al., ARTIST, Nature Communications 15, 6997, 2024: actuator initial
   stroke and angle as calibration parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.aiming import angle_mrad
from controller.geometry.design import beam_jacobians, tangents
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.pose_batch import normal_and_center
from controller.geometry.tracking_model import (
    NAMES,
    PRIOR_SIGMA_SI,
    TERMS,
    TrackingModel,
    implied_normal,
    model_normal,
)
from controller.geometry.vectors import unit

_OFFSETS = np.array([NAMES.index("az_offset"), NAMES.index("el_offset")])
HUBER_C = 3.0
MAX_STEPS = 12
IDENTIFIED_RATIO = 0.5
MIN_DOF_FOR_NOISE = 10.0


class NotIdentifiable(InputError):
    """The measurements determine no term of the model: they cannot support a fit."""


@dataclass(frozen=True, eq=False)  # numpy fields
class Sample:
    """One pointing measurement: unit ENU ``source_dir`` (towards the source), commanded
    motor steps, measured beam centroid ``spot_enu`` (m ENU), and a ``weight`` (1: full; less
    for an old measurement after drift)."""

    source_dir: np.ndarray
    az_steps: float
    el_steps: float
    spot_enu: np.ndarray
    weight: float = 1.0
    source_pos: np.ndarray | None = None  # a lamp's position, m ENU (None: the sun, at infinity)
    epoch: int = 0  # the night it was taken, counted back from the newest (Eq. 3 of the module)


@dataclass(frozen=True, eq=False)  # numpy fields
class ModelFit:
    """Result of :func:`fit_model`.

    ``model``: fitted values; ``sigma``: 1-σ per term (SI); ``covariance`` (SI²);
    ``identified``: per term, whether the data determined it (σ < ½ prior σ); ``residual_mrad``
    per sample (angle between model and measured normals) and its RMS before/after;
    ``weights``: final robust weights; ``noise_scale`` s of Eq. (2); ``condition``: condition
    number of the data Jacobian over the identified terms (prior-whitened); ``converged``:
    whether the Gauss-Newton steps and robust weights settled within :data:`MAX_STEPS`."""

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


def fit_model(kin: HeliostatKinematics, samples: Sequence[Sample], *, noise_mrad: float = 0.3,
              prior: TrackingModel | None = None, prior_sigma: np.ndarray | None = None,
              robust: bool = True, epoch_sigma: dict[int, float] | None = None) -> ModelFit:
    """MAP fit of Eq. (1); Σ of Eq. (2). ``prior`` (default zero) is p₀; ``prior_sigma`` (SI,
    default :data:`TERMS`' σ) may be narrowed (e.g. the posterior of a previous night).
    ``epoch_sigma``: σ_e (rad) of the reference drift of each earlier night e (Eq. 3); samples
    of a night not in it share the newest night's references.

    Raises InputError when there are no samples, a sample is not finite, or the samples
    identify no term (they cannot support a fit)."""
    if not samples:
        raise InputError("model fit: no measurements")
    if not (np.isfinite(noise_mrad) and noise_mrad > 0):
        raise InputError(f"model fit: noise must be a positive number of mrad, got {noise_mrad}")
    for i, s in enumerate(samples):
        vals = np.concatenate([np.ravel(s.source_dir), [s.az_steps, s.el_steps, s.weight],
                               np.ravel(s.spot_enu)])
        if not np.all(np.isfinite(vals)) or s.weight <= 0:
            raise InputError(f"model fit: measurement {i + 1} has a non-finite value or weight <= 0")
    p0 = (prior or TrackingModel.zero()).values
    npar = len(p0)
    drifting = sorted({s.epoch for s in samples if s.epoch != 0 and s.epoch in (epoch_sigma or {})})
    slot = {e: npar + 2 * i for i, e in enumerate(drifting)}
    s0 = PRIOR_SIGMA_SI if prior_sigma is None else np.asarray(prior_sigma, float)
    s0 = np.concatenate([s0, np.repeat([float(epoch_sigma[e]) for e in drifting], 2)]) if drifting else s0
    sig_n = noise_mrad * 1e-3
    # The measured normals move with the mirror centre (position terms, Eq. 4 of the model):
    # they are re-evaluated with the model; the tangent bases stay those at the prior.
    bases = np.stack([tangents(measured_normal(kin, TrackingModel(p0), s)) for s in samples])  # (S, 2, 3)
    age_w = np.array([s.weight for s in samples])
    steps = np.array([[s.az_steps, s.el_steps] for s in samples], float)
    spots = np.array([np.ravel(s.spot_enu) for s in samples], float)
    lamps = np.array([np.ravel(s.source_pos) if s.source_pos is not None else np.zeros(3) for s in samples],
                     float)
    has_lamp = np.array([s.source_pos is not None for s in samples])[:, None]
    src_dir = unit(np.array([np.ravel(s.source_dir) for s in samples], float))
    # Each sample's terms from the whitened x: p₀ + G_s (x σ₀), G_s adding its night's
    # reference offsets (Eq. 3) to the newest night's.
    g = np.zeros((len(samples), npar, len(s0)))
    g[:, np.arange(npar), np.arange(npar)] = 1.0
    for i, sm in enumerate(samples):
        if sm.epoch in slot:
            g[i, _OFFSETS, slot[sm.epoch] + np.arange(2)] = 1.0

    def epoch_model(x: np.ndarray, epoch: int | None) -> TrackingModel:
        """The model of Eq. (3) on night ``epoch`` (None: the newest night's references)."""
        p = p0 + x[:npar] * s0[:npar]
        if epoch is not None:
            j = slot[epoch]
            p = p.copy()
            p[_OFFSETS] += x[j:j + 2] * s0[j:j + 2]
        return TrackingModel(p)

    def residuals(xs: np.ndarray) -> np.ndarray:
        """The whitened data residuals (B, 2S) at each row of ``xs`` (B, L), all at once."""
        params = p0 + np.einsum("snl,bl->bsn", g, xs * s0)
        n, center = normal_and_center(kin, params, steps)
        src = np.where(has_lamp, unit(lamps - center), src_dir)
        implied = unit(src + unit(spots - center))
        return np.einsum("sij,bsj->bsi", bases, n - implied).reshape(len(xs), -1) / sig_n

    def data_res(x: np.ndarray) -> np.ndarray:
        return residuals(x[None])[0]

    def data_jac(x: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals at x, their forward-difference Jacobian (2S, L) with per-term ``step``)."""
        r = residuals(np.vstack([x, x + np.diag(step)]))
        return r[0], ((r[1:] - r[0]) / step[:, None]).T

    # Gauss-Newton on the prior-whitened terms x (p = p₀ + x σ₀) with iteratively reweighted
    # (Huber) samples: the problem is nearly linear, so a few steps converge.
    weights = np.ones(len(samples))
    x = np.zeros(len(s0))
    step = np.full(len(x), 1e-4)
    converged = False
    for _ in range(MAX_STEPS):
        w = np.repeat(np.sqrt(weights * age_w), 2)
        r, jac = data_jac(x, step)
        jd = w[:, None] * jac
        dx = -np.linalg.solve(jd.T @ jd + np.eye(len(x)), jd.T @ (w * r) + x)
        x = x + dx
        norms = np.sqrt(age_w) * np.linalg.norm(data_res(x).reshape(-1, 2), axis=1)
        new = np.minimum(1.0, HUBER_C / np.maximum(norms, 1e-12)) if robust else weights
        if np.max(np.abs(dx)) < 1e-6 and np.allclose(new, weights, atol=1e-3):
            converged = True
            break
        weights = new
    w = np.repeat(np.sqrt(weights * age_w), 2)
    jd = w[:, None] * data_jac(x, step)[1]
    post_x = np.linalg.inv(jd.T @ jd + np.eye(len(x)))  # covariance of x (prior-whitened)
    ratio2 = np.clip(np.diag(post_x), 0.0, 1.0)
    p_eff = float(np.sum(1.0 - ratio2))
    chi2 = float(np.sum((w * data_res(x)) ** 2))
    dof = 2 * len(samples) - p_eff
    # The stated noise is a floor: residuals larger than it (noise or effects the model lacks)
    # widen the uncertainty once there are enough of them to tell; smaller ones never narrow it.
    s2 = max(1.0, chi2 / dof) if dof >= MIN_DOF_FOR_NOISE else 1.0
    cov = (s2 * post_x * np.outer(s0, s0))[:npar, :npar]  # the terms' marginal (drift offsets out)
    sigma = np.sqrt(np.diag(cov))
    identified = np.sqrt(ratio2[:npar]) * np.sqrt(s2) < IDENTIFIED_RATIO
    if not identified.any():
        raise NotIdentifiable(f"model fit: {len(samples)} measurement(s) identify no term of the model "
                         f"(every σ stays above {IDENTIFIED_RATIO:g}× its prior); measure more geometries")
    sv = np.linalg.svd(jd[:, :npar][:, identified], compute_uv=False)
    model = epoch_model(x, None)
    res = np.array([normal_residual_mrad(kin, epoch_model(x, s.epoch if s.epoch in slot else None), s)
                    for s in samples])
    res0 = np.array([normal_residual_mrad(kin, TrackingModel(p0), s) for s in samples])
    return ModelFit(model, sigma, cov, identified, res, float(np.sqrt(np.mean(res**2))),
                    float(np.sqrt(np.mean(res0**2))), weights, float(np.sqrt(s2)), float(sv[0] / sv[-1]),
                    converged)


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
