"""The correction step of one measurement: the library's coarse correction or the centroid's fine one.

On the first measurement of a cycle the recognised error case may give the move instead of the
centroid (the paper's coarse correction), in two forms:

* a library entry's stored axis ``correction_deg`` (Δazimuth, Δelevation of the axes, deg),
  applied as it is (``Pointing.coarse_correction``);
* the match's interpolated beam pointing error ``coarse_correction_deg`` = −(Δaz, Δel) of the
  reflected beam (deg, azimuth clockwise from north), when its ``confidence`` reaches
  ``min_confidence`` (config ``calibration.coarse_correction``; None = never). The beam error
  is turned into the spot offset it causes on the target, to first order
  offset = R · (b(az + Δaz, el + Δel) − b(az, el)) with b the unit beam direction and R the
  slant range heliostat → aim point, and that offset goes through the same Jacobian
  (``Pointing.fine_correction``, Eq. 1) as a measured centroid offset.

Otherwise (later measurements, an unknown or unconfident match, a clipped spot) the centroid
offset gives the fine correction. Either way the result is a :class:`Step` that the state
machine clamps to the drive's limits like every other move.
"""

from __future__ import annotations

import numpy as np

from controller.calibration.context import Pointing
from controller.calibration.observations import Match, Observation, Step
from controller.geometry.vectors import azel_to_vector, unit, vector_to_azel


def predicted_offset_enu(pointing: Pointing, error_deg: tuple[float, float]) -> np.ndarray:
    """Spot offset (m, ENU) on the target caused by a beam error (Δaz, Δel) in degrees.

    First order: R · (b1 − b0), b0 = unit(aim − heliostat), b1 = b0 turned by the error in
    azimuth (clockwise from north) and elevation, R = |aim − heliostat|."""
    d = np.asarray(pointing.aim_point, float) - np.asarray(pointing.heliostat_pos, float)
    b0 = unit(d)
    az, el = vector_to_azel(b0)
    b1 = azel_to_vector(float(az) + error_deg[0], float(el) + error_deg[1])
    return float(np.linalg.norm(d)) * (np.asarray(b1, float) - b0)


def coarse_applies(match: Match | None, min_confidence: float | None) -> bool:
    """Whether the match's interpolated coarse correction is to be applied (known, confident)."""
    return (min_confidence is not None and match is not None and not match.unknown
            and match.coarse_correction_deg is not None and match.confidence >= min_confidence)


def correction_step(pointing: Pointing, az_steps: int, el_steps: int, obs: Observation, match: Match | None,
                    *, first: bool, min_confidence: float | None) -> tuple[str, Step]:
    """(``"coarse"`` or ``"fine"``, the step) for the measurement ``obs`` taken at the pose."""
    if first and not obs.clipped and match is not None and not match.unknown:
        if match.correction_deg is not None and any(abs(c) > 0 for c in match.correction_deg):
            return "coarse", pointing.coarse_correction(az_steps, el_steps, *match.correction_deg)
        if coarse_applies(match, min_confidence):
            error = (-match.coarse_correction_deg[0], -match.coarse_correction_deg[1])
            offset = predicted_offset_enu(pointing, error)
            return "coarse", pointing.fine_correction(az_steps, el_steps, offset)
    offset = np.asarray(obs.centroid_enu) - pointing.aim_point
    return "fine", pointing.fine_correction(az_steps, el_steps, offset)
