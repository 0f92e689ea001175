"""Auto-exposure of the double-CCD pair: step both exposures by a common factor (keeping their
ratio) until the longer exposure has useful signal and the shorter one is not saturated in the
beam core.

Rule for one frame pair (pure, no I/O: :func:`next_exposures`; the capture loop around it is
:func:`controller.calibration.cycle.exposure.auto_expose`):

* LOW has more than ``max_saturated`` pixels at ``z_max`` (its beam core clips): divide both
  exposures by ``step``;
* otherwise, if HIGH's peak signal above the dark offset is below ``useful_fraction`` of the
  range and LOW's peak would stay below the clip after multiplying by ``step``: multiply both
  by ``step``;
* otherwise the exposures are right.

Signal scales linearly with exposure time (to within the response's curvature), which is why
the prediction uses the peak signal above the dark offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ExposureStep:
    """Decision for one pair: ``action`` is "shorter", "longer" or "ok"; peaks in counts."""

    exposures: tuple[float, float]
    action: str
    low_saturated_px: int
    high_peak: float
    low_peak: float


def next_exposures(low: np.ndarray, high: np.ndarray, exposures: tuple[float, float], *,
                   bit_depth: int = 8, dark_offset: float = 8.0, useful_fraction: float = 0.5,
                   max_saturated: int = 0, step: float = 2.0, limits_s: tuple[float, float] = (1e-5, 1.0)
                   ) -> ExposureStep:
    """Next exposures (seconds, LOW first) for a pair (2-D integer arrays); see the module rule."""
    z_max = (1 << bit_depth) - 1
    span = z_max - dark_offset
    sat = int(np.count_nonzero(np.asarray(low) >= z_max))
    low_peak = float(np.max(low)) - dark_offset
    high_peak = float(np.max(high)) - dark_offset
    t1, t2 = exposures
    if sat > max_saturated and t1 / step >= limits_s[0]:
        return ExposureStep((t1 / step, t2 / step), "shorter", sat, high_peak, low_peak)
    if (sat <= max_saturated and high_peak < useful_fraction * span and low_peak * step < span
            and t2 * step <= limits_s[1]):
        return ExposureStep((t1 * step, t2 * step), "longer", sat, high_peak, low_peak)
    return ExposureStep((t1, t2), "ok", sat, high_peak, low_peak)
