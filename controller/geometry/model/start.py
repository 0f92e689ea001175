"""Where the fit of the tracking model starts, and a properties file it cannot start from.

Real heliostats miss by far more than the prior σ of their terms: the nominal kinematics of
the 16 Jülich heliostats of PAINT miss by 10–95 mrad. Gauss–Newton from the nominal model
then spends its steps on the bulk offset, and a redescending robust weight (Cauchy) would
call every measurement an outlier. The start is therefore the prior's model with the two
joint references moved by the median difference between measured and modelled normals,

    Δα₀ = median_k (asin m_k,E − asin n_k,E),
    Δε₀ = median_k (atan2(−m_k,N, m_k,U) − atan2(−n_k,N, n_k,U))                           (1)

(the angles of kinematics Eq. 3; the median so that a few wrong records do not move it).

A properties file can be wrong in a way the kinematics cannot evaluate: an actuator whose
initial stroke length puts the stroke at the measurements' motor steps, anywhere in its step
range or at 0 steps (the law's reference) outside the actuator's triangle [|o − r|, o + r]
(actuators Eq. 1) has no joint angle there. Such an actuator's initial stroke is not believed:
its prior becomes N(L_mid − L₀, σ_L²), L_mid the middle of the strokes that keep every measurement and 0 steps
inside the triangle (for steps s_min … s_max, 0 among them: [|o − r| − s_min/k,
o + r − s_max/k]), σ_L = :data:`SUSPECT_STROKE_SIGMA_M`, and its joint
reference gets σ = :data:`SUSPECT_OFFSET_SIGMA_RAD` (the file's initial angle is suspect too).
The actuator's law itself identifies L₀: its curvature over the stroke depends on it.

Units: SI (rad, m); motor steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.actuators import LinearActuator
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import NAMES
from controller.geometry.pose_batch import normal_and_center
from controller.geometry.vectors import unit

SUSPECT_STROKE_SIGMA_M = 0.1
SUSPECT_OFFSET_SIGMA_RAD = 0.3
_I = {n: i for i, n in enumerate(NAMES)}
_AXES = (("azimuth", "az_stroke0", "az_offset", 0), ("elevation", "el_stroke0", "el_offset", 1))


@dataclass(frozen=True, eq=False)  # numpy fields
class Start:
    """The fit's prior mean ``prior`` and σ ``sigma`` (SI) after any actuator repair, the
    start ``values`` (SI), one ``notes`` line per repaired actuator, and ``at_prior``: the
    normals and implied normals (S, 3 each) at ``prior``, which the start is taken from."""

    prior: np.ndarray
    sigma: np.ndarray
    values: np.ndarray
    notes: tuple[str, ...]
    at_prior: tuple[np.ndarray, np.ndarray]


def implied_normals(centers: np.ndarray, source_dirs: np.ndarray, spots: np.ndarray,
                    lamps: np.ndarray | None = None) -> np.ndarray:
    """Bisector normals (S, 3) of the source direction (towards the lamp at ``lamps`` where
    finite, else ``source_dirs``) and the direction from each mirror centre to its spot."""
    src = source_dirs
    if lamps is not None:
        lit = np.isfinite(lamps).all(axis=1, keepdims=True)
        # Every sample under a lamp (a night's refit): the lamps' directions as they are.
        src = unit(lamps - centers) if lit.all() else np.where(lit, unit(np.nan_to_num(lamps) - centers),
                                                                source_dirs)
    return unit(unit(src) + unit(spots - centers))


def _feasible_stroke(act: LinearActuator, steps: np.ndarray) -> tuple[float, float]:
    """(lowest, highest) initial stroke, m, that keeps the stroke at every one of ``steps``
    and at 0 steps (the law's reference, actuators Eq. 3) inside the actuator's triangle."""
    lo = abs(act.offset - act.pivot_radius) - min(float(np.min(steps)), 0.0) / act.increment
    hi = act.offset + act.pivot_radius - max(float(np.max(steps)), 0.0) / act.increment
    return lo, hi


def repair(kin: HeliostatKinematics, prior: np.ndarray, sigma: np.ndarray,
           steps: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The prior (mean, σ) with every actuator that leaves its triangle at ``steps`` (S, 2:
    az, el) re-seated as the module docstring says, and a note per actuator. InputError when
    no initial stroke could keep all the steps inside the triangle."""
    prior, sigma, notes = prior.copy(), sigma.copy(), []
    for axis, stroke_term, offset_term, col in _AXES:
        act: LinearActuator = getattr(kin, axis)
        # The actuator travels its whole range: a file whose stroke leaves the triangle anywhere
        # in it is wrong, even where no record went.
        s = np.concatenate([steps[:, col], [act.min_increment, act.max_increment]])
        l0 = act.initial_stroke_length + prior[_I[stroke_term]]
        stroke = np.append(s, 0.0) / act.increment + l0
        lowest, highest = abs(act.offset - act.pivot_radius), act.offset + act.pivot_radius
        outside = np.maximum(lowest - stroke, stroke - highest)
        if (outside <= 0).all():
            continue
        lo, hi = _feasible_stroke(act, s)
        if not lo < hi:
            raise InputError(f"heliostat {kin.heliostat_id}: the {axis} actuator's steps span "
                             f"{np.ptp(s) / act.increment:.3f} m of stroke, more than its triangle allows "
                             f"(offset {act.offset} m, pivot radius {act.pivot_radius} m): "
                             "check its properties")
        worst = float(np.append(s, 0.0)[np.argmax(outside)])
        mid = (lo + hi) / 2.0
        prior[_I[stroke_term]] = mid - act.initial_stroke_length
        sigma[_I[stroke_term]] = max(sigma[_I[stroke_term]], SUSPECT_STROKE_SIGMA_M)
        sigma[_I[offset_term]] = max(sigma[_I[offset_term]], SUSPECT_OFFSET_SIGMA_RAD)
        notes.append(f"heliostat {kin.heliostat_id}: the properties put the {axis} actuator's stroke outside "
                     f"its triangle at {worst:,.0f} steps (initial stroke length "
                     f"{act.initial_stroke_length:.4f} m, "
                     f"allowed {max(lo, 0.0):.4f}–{hi:.4f} m); its initial stroke length and reference are "
                     f"fitted (start {mid:.4f} m, prior σ {1e3 * sigma[_I[stroke_term]]:.0f} mm and "
                     f"{1e3 * sigma[_I[offset_term]]:.0f} mrad)")
    return prior, sigma, tuple(notes)


def start(kin: HeliostatKinematics, prior: np.ndarray, sigma: np.ndarray, steps: np.ndarray,
          source_dirs: np.ndarray, spots: np.ndarray, lamps: np.ndarray | None = None) -> Start:
    """The prior after :func:`repair` and the start of Eq. (1) for measurements at ``steps``
    (S, 2), sources ``source_dirs`` (S, 3) or ``lamps`` (S, 3; NaN rows: the sun) and
    measured ``spots`` (S, 3, m ENU)."""
    prior, sigma, notes = repair(kin, prior, sigma, steps)
    n, c = normal_and_center(kin, prior[None, :], steps)
    m = implied_normals(c, source_dirs, spots, lamps)
    d_az = np.arcsin(np.clip(m[:, 0], -1, 1)) - np.arcsin(np.clip(n[:, 0], -1, 1))
    d_el = np.arctan2(-m[:, 1], m[:, 2]) - np.arctan2(-n[:, 1], n[:, 2])
    values = prior.copy()
    values[_I["az_offset"]] += float(np.median(d_az))
    values[_I["el_offset"]] += float(np.median(d_el))
    return Start(prior, sigma, values, notes, (n, m))
