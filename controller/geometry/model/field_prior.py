"""A field's prior of the tracking-model terms, learned from its heliostats' fitted models.

Heliostats of one field are built alike, and their terms scatter within a spread the field's
own fits show (on the 16 Jülich heliostats of PAINT: the mirror offset 0–13 mrad, the
elevation reference −16 to 1 mrad, the base yaw −35 to 98 mrad). A heliostat with few
measurements then fits best against that spread rather than the generic prior.

Per term, with the fitted values v_h of the H heliostats whose fit identified the term, the
field is N(μ, τ²) with

    μ = mean_h v_h,   τ² = Σ_h (v_h − μ)² / (H − 1)                                  (1)

the sample mean and variance [1]. Each fit's own posterior variance is *not* subtracted from
τ² (the random-effects estimate of meta-analysis would): the terms are correlated (the
elevation reference and the mirror offset share a rotation at α = 0, the azimuth reference
and the base yaw another), so one term's marginal σ overstates what a fit leaves unknown of
the combinations the field shares, and subtracting it pinned those terms — on the Jülich
field the 5-record fits were then worse than with the generic prior. Where fewer than
:data:`MIN_HELIOSTATS` fits identified a term, the field says nothing about it and it keeps its
generic prior (mean 0, the documented σ). The field σ is τ, floored at :data:`FLOOR` of the
generic σ so that no term is pinned by a handful of alike heliostats.

Units: SI (rad, m) in, SI out.

References
----------
.. [1] A. Gelman et al., "Bayesian Data Analysis", 3rd ed., CRC 2013, Sec. 5.4–5.6: the
   hierarchical normal model, whose population mean and variance (1) estimates; R.
   DerSimonian, N. Laird, Controlled Clinical Trials 7, 177–188, 1986, for the estimate that
   subtracts each study's variance (not used here, see above).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.model.tracking import PRIOR_SIGMA_SI

MIN_HELIOSTATS = 3
FLOOR = 0.1


@dataclass(frozen=True, eq=False)  # numpy fields
class FieldPrior:
    """``mean`` and ``sigma`` (SI) of every term; ``count`` per term, how many heliostats'
    fits identified it (0: the generic prior kept)."""

    mean: np.ndarray
    sigma: np.ndarray
    count: np.ndarray


def field_prior(values: np.ndarray, identified: np.ndarray) -> FieldPrior:
    """The field prior of Eq. (1) from H fitted models: ``values`` (H, n) SI, ``identified``
    (H, n) bool. InputError for fewer than two models."""
    v, ok = np.asarray(values, float), np.asarray(identified, bool)
    if v.ndim != 2 or len(v) < 2:
        raise InputError("model prior: needs the fitted models of at least two heliostats")
    mean, sigma = np.zeros(v.shape[1]), PRIOR_SIGMA_SI.copy()
    count = ok.sum(axis=0)
    for i in range(v.shape[1]):
        if count[i] < MIN_HELIOSTATS:
            continue
        known = v[ok[:, i], i]
        mean[i] = float(np.mean(known))
        sigma[i] = max(float(np.std(known, ddof=1)), FLOOR * PRIOR_SIGMA_SI[i])
    return FieldPrior(mean, sigma, count)
