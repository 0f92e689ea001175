"""A field's prior of the tracking-model terms, learned from its heliostats' fitted models.

Heliostats of one field are built alike, and their terms scatter within a spread the field's
own fits show (on the 16 Jülich heliostats of PAINT: the mirror offset 0–13 mrad, the
elevation reference −16 to 1 mrad, the base yaw −35 to 98 mrad). A heliostat with few
measurements then fits best against that spread rather than the generic prior.

Per term, with the fitted values v_h and their posterior variances s_h² of H heliostats,
the field is N(μ, τ²) and each fit a draw from it seen with its own uncertainty,

    v_h ~ N(μ, τ² + s_h²),                                                   (1)

and (μ, τ²) are their maximum-likelihood estimate, found by the fixed point

    w_h = 1 / (τ² + s_h²),  μ = Σ w_h v_h / Σ w_h,
    τ² = max(0, Σ w_h² ((v_h − μ)² − s_h²) / Σ w_h²)                         (2)

(the random-effects estimate of meta-analysis [1]). Only the heliostats whose fit identified
the term count: where fewer than :data:`MIN_HELIOSTATS` did, the field says nothing about the
term and it keeps its generic prior (mean 0, the documented σ). The field σ is τ, floored at
:data:`FLOOR` of the generic σ so that no term is pinned by a handful of alike heliostats.

Units: SI (rad, m) in, SI out.

References
----------
.. [1] R. DerSimonian, N. Laird, "Meta-analysis in clinical trials", Controlled Clinical
   Trials 7, 177–188, 1986; A. Gelman et al., "Bayesian Data Analysis", 3rd ed., CRC 2013,
   Sec. 5.4 and 5.6 (hierarchical normal model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.tracking_model import PRIOR_SIGMA_SI

MIN_HELIOSTATS = 3
FLOOR = 0.1
_ITERATIONS = 200


@dataclass(frozen=True, eq=False)  # numpy fields
class FieldPrior:
    """``mean`` and ``sigma`` (SI) of every term; ``count`` per term, how many heliostats'
    fits identified it (0: the generic prior kept)."""

    mean: np.ndarray
    sigma: np.ndarray
    count: np.ndarray


def random_effects(values: np.ndarray, variances: np.ndarray) -> tuple[float, float]:
    """(μ, τ²) of Eq. (2) for one term's fitted ``values`` and their ``variances`` (H,)."""
    v, s2 = np.asarray(values, float), np.asarray(variances, float)
    tau2 = float(np.var(v))
    mu = float(np.mean(v))
    for _ in range(_ITERATIONS):
        w = 1.0 / (tau2 + s2 + 1e-30)
        mu = float(np.sum(w * v) / np.sum(w))
        new = max(0.0, float(np.sum(w**2 * ((v - mu) ** 2 - s2)) / np.sum(w**2)))
        if abs(new - tau2) <= 1e-9 * max(new, 1e-30):
            tau2 = new
            break
        tau2 = new
    return mu, tau2


def field_prior(values: np.ndarray, sigmas: np.ndarray, identified: np.ndarray) -> FieldPrior:
    """The field prior of Eq. (1)-(2) from H fitted models: ``values`` and ``sigmas`` (H, n)
    SI, ``identified`` (H, n) bool. InputError for fewer than two models."""
    v, s, ok = np.asarray(values, float), np.asarray(sigmas, float), np.asarray(identified, bool)
    if v.ndim != 2 or len(v) < 2:
        raise InputError("model prior: needs the fitted models of at least two heliostats")
    mean, sigma = np.zeros(v.shape[1]), PRIOR_SIGMA_SI.copy()
    count = ok.sum(axis=0)
    for i in range(v.shape[1]):
        if count[i] < MIN_HELIOSTATS:
            continue
        mu, tau2 = random_effects(v[ok[:, i], i], s[ok[:, i], i] ** 2)
        mean[i] = mu
        sigma[i] = max(np.sqrt(tau2), FLOOR * PRIOR_SIGMA_SI[i])
    return FieldPrior(mean, sigma, count)
