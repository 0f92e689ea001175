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

Fine steps after the run's first one are corrected by what that one did (:func:`step_response`):
the nominal kinematics' Jacobian of a heliostat tens of mrad off moves the spot a tenth short or
aside, so a 20 mrad first error took three corrections to reach 0.5 mrad and landed anywhere
below it. With w the move the first fine step was to make on the target (m ENU, in its plane;
planned with the Jacobian alone) and g the move it made, the response is the rank-1 secant
update of the identity (Broyden's "good" update [1]),

    M = I + (g − w) wᵀ / (wᵀ w),   M⁻¹ x = x − (g − w) (wᵀ x) / (wᵀ g)                     (1)

(Sherman–Morrison), and the next step is planned for M⁻¹ d instead of the wanted move d; used
when |w| ≥ :data:`RESPONSE_MIN_M` (a smaller move is lost in the centroid's noise) and
det M = wᵀg / wᵀw within :data:`RESPONSE_DET` (else none).

.. [1] C. G. Broyden, "A class of methods for solving nonlinear simultaneous equations", Math.
   Comp. 19, 577–593, 1965.
"""

from __future__ import annotations

import numpy as np

from controller.calibration.cycle.context import Pointing
from controller.calibration.cycle.observations import Observation, Step
from controller.calibration.records import RunRecord
from controller.recognition.library import Match

RESPONSE_MIN_M = 0.3  # the least move (m on the target) whose response is measured
RESPONSE_DET = (0.5, 2.0)  # det M of a usable response (Eq. 1)


def clipped_applies(obs: Observation, min_confidence: float | None) -> bool:
    """Whether the clipped spot's centre estimate is to give the move (enabled, known, confident)."""
    if min_confidence is None or not obs.clipped or obs.clipped_centre_enu is None:
        return False
    return bool(np.all(np.isfinite(obs.clipped_centre_enu))) and obs.clipped_confidence >= min_confidence


def step_response(run: RunRecord | None) -> tuple[np.ndarray, np.ndarray] | None:
    """(w, g) of Eq. (1), m ENU, from the run's first two measurements and the one fine step
    between them; None when there is none or it is not usable."""
    if run is None or len(run.measurements) < 2:
        return None
    a, b = run.measurements[0], run.measurements[1]
    steps = [c for c in run.corrections if c.iteration == a.iteration]
    if [c.kind for c in steps] != ["fine"] or a.centroid_enu is None or b.centroid_enu is None:
        return None
    want = np.asarray(a.aim_enu, float) - np.asarray(a.centroid_enu, float)
    got = np.asarray(b.centroid_enu, float) - np.asarray(a.centroid_enu, float)
    ww = float(want @ want)
    if ww < RESPONSE_MIN_M**2 or not RESPONSE_DET[0] <= float(want @ got) / ww <= RESPONSE_DET[1]:
        return None
    return want, got


def correction_step(pointing: Pointing, az_steps: int, el_steps: int, obs: Observation, match: Match | None,
                    *, first: bool, min_confidence: float | None,
                    run: RunRecord | None = None) -> tuple[str, Step]:
    """(``"coarse"`` or ``"fine"``, the step) for the look ``obs`` taken at the pose; ``run`` (its
    measurements and corrections so far) corrects a fine step by the first one's response (Eq. 1)."""
    if first and not obs.clipped and match is not None and not match.unknown:
        if match.correction_deg is not None and any(abs(c) > 0 for c in match.correction_deg):
            return "coarse", pointing.coarse_correction(az_steps, el_steps, *match.correction_deg)
    if clipped_applies(obs, min_confidence):
        offset = np.asarray(obs.clipped_centre_enu, float) - pointing.aim_point
        return "coarse", pointing.fine_correction(az_steps, el_steps, offset)
    offset = np.asarray(obs.centroid_enu) - pointing.aim_point
    response = step_response(run)
    if response is not None:  # plan the move that, as the first step responded, removes the offset
        w, g = response
        offset = offset - (g - w) * float(w @ offset) / float(w @ g)
    return "fine", pointing.fine_correction(az_steps, el_steps, offset)
