"""The correction step of one look: the coarse correction or the centroid's fine one.

Where the coarse correction applies (measured in docs/recognition.md, "Coarse correction in the
loop"):

* a library entry's stored axis ``correction_deg`` (Δazimuth, Δelevation of the axes, deg), on
  the first measurement of a known match: applied as it is (``Pointing.coarse_correction``);
* a spot clipped by the camera view's edge, when ``calibration.coarse_correction`` is set
  (None = never) and the clipped spot's centre estimate (:mod:`controller.imaging.clipped_spot`,
  from its half-maximum contour) has a confidence of at least that value: the move puts that
  centre on the aim point, through the same Jacobian as a centroid offset
  (``Pointing.fine_correction``, Eq. 1). The visible part's energy centroid is biased inward, so
  a move on it falls short and the next look is clipped again.

The library match's interpolated beam error (``Match.coarse_correction_deg``) is *not* applied:
it knows only the pointing part of the recognised case, while the centroid of a spot in full
view measures the whole error (the simulated campaign took more iterations with it).

Otherwise the centroid offset gives the fine correction (for a clipped spot without a confident
centre: towards the visible part, look again). Either way the result is a :class:`Step` that the
state machine clamps to the drive's limits like every other move.
"""

from __future__ import annotations

import numpy as np

from controller.calibration.cycle.context import Pointing
from controller.calibration.cycle.observations import Observation, Step
from controller.recognition.library import Match


def clipped_applies(obs: Observation, min_confidence: float | None) -> bool:
    """Whether the clipped spot's centre estimate is to give the move (enabled, known, confident)."""
    if min_confidence is None or not obs.clipped or obs.clipped_centre_enu is None:
        return False
    return bool(np.all(np.isfinite(obs.clipped_centre_enu))) and obs.clipped_confidence >= min_confidence


def correction_step(pointing: Pointing, az_steps: int, el_steps: int, obs: Observation, match: Match | None,
                    *, first: bool, min_confidence: float | None) -> tuple[str, Step]:
    """(``"coarse"`` or ``"fine"``, the step) for the look ``obs`` taken at the pose."""
    if first and not obs.clipped and match is not None and not match.unknown:
        if match.correction_deg is not None and any(abs(c) > 0 for c in match.correction_deg):
            return "coarse", pointing.coarse_correction(az_steps, el_steps, *match.correction_deg)
    if clipped_applies(obs, min_confidence):
        offset = np.asarray(obs.clipped_centre_enu, float) - pointing.aim_point
        return "coarse", pointing.fine_correction(az_steps, el_steps, offset)
    offset = np.asarray(obs.centroid_enu) - pointing.aim_point
    return "fine", pointing.fine_correction(az_steps, el_steps, offset)
