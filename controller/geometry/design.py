"""Experimental design for the tracking model: which geometry to measure next.

A measurement at motor steps (s_az, s_el) observes the two tangential components of the
mirror normal n(p) (:mod:`controller.geometry.model_fit`, Eq. 1) with noise σ_n, so with
H = ∂(t₁·n, t₂·n)/∂p (2 × p) the posterior covariance of the model terms becomes

    Σ' = Σ − Σ Hᵀ (σ_n² I + H Σ Hᵀ)⁻¹ H Σ                                  (1)

(the Kalman / Woodbury update of a linear-Gaussian observation). What calibration is for is
the daytime pointing: with A_k = ∂r_k/∂p the Jacobian of the reflected beam at sun position
k (the heliostat aiming with the model), the expected squared daytime error is

    V(Σ) = mean_k tr(A_k Σ A_kᵀ)                                            (2)

and a candidate's *gain* is V(Σ) − V(Σ'), the expected-variance reduction (an A-optimal
design weighted by the daytime geometry [1]). :func:`greedy_design` picks candidates one at
a time by gain, updating Σ after each pick, which is within (1 − 1/e) of the best set for
this submodular objective [2].

Units: model terms SI (rad, m); σ_n rad; V in rad².

References
----------
.. [1] F. Pukelsheim, "Optimal Design of Experiments", SIAM 2006, ch. 9 (A- and linear
   optimality).
.. [2] A. Krause, A. Singh, C. Guestrin, "Near-optimal sensor placements in Gaussian
   processes", JMLR 9, 235-284, 2008.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controller.errors import LimitError
from controller.geometry.kinematics import BODY_NORMAL, HeliostatKinematics
from controller.geometry.tracking_model import (
    TrackingModel,
    bisector_normal,
    model_aim,
    model_normal,
    poses,
)
from controller.geometry.vectors import unit


def jacobian(fun, x: np.ndarray, step: np.ndarray, fx: np.ndarray | None = None) -> np.ndarray:
    """Forward-difference Jacobian of ``fun`` at ``x`` with per-coordinate ``step`` (``fx``:
    fun(x) when known): the model's residuals are nearly linear over the steps used here, so
    half the calls of a central difference lose nothing that matters."""
    f0 = fun(x) if fx is None else fx
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = step[i]
        cols.append((fun(x + d) - f0) / step[i])
    return np.stack(cols, axis=-1)


def tangents(n: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) perpendicular to the unit vector ``n`` and to each other."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = unit(np.cross(helper, n))
    return np.stack([t1, np.cross(n, t1)])


_STEP = 1e-6  # rad or m: well inside the linear range of every term, far above rounding


def normal_jacobian(kin: HeliostatKinematics, model: TrackingModel, az_steps: float, el_steps: float,
                    source_dir, spot, source_pos=None) -> np.ndarray:
    """H of Eq. (1) for a spot expected at ``spot`` (m ENU) under a source at ``source_dir``
    (the sun) or ``source_pos`` (a lamp, m ENU): ∂(t₁·(n − m), t₂·(n − m))/∂p at the given
    steps, with m the normal the spot implies (it moves with the position terms), (2, p), per
    SI unit of each term."""
    base = tangents(model_normal(kin, model, az_steps, el_steps))

    def observed(v: np.ndarray) -> np.ndarray:
        m = TrackingModel(v)
        rot = poses(kin, m, [(az_steps, el_steps)])[0]
        center = kin.position + m.position_offset() + rot @ kin.concentrator_translation
        return base @ (rot @ BODY_NORMAL - bisector_normal(center, source_dir, spot, source_pos))

    return jacobian(observed, model.values, np.full(len(model.values), _STEP))


def beam_jacobians(kin: HeliostatKinematics, model: TrackingModel, source_dirs: np.ndarray,
                   aim_point) -> np.ndarray:
    """A_k of Eq. (2), (k, 3, p): the sensitivity to the terms of the reflected beam's error —
    the beam r = 2(s·n)n − s less the direction from the mirror centre to ``aim_point`` (m ENU),
    which the position terms move — at the steps the model aims with for each reachable source
    direction (unit ENU, towards the source). Unreachable directions are left out (k may be 0)."""
    aim_point = np.asarray(aim_point, float)
    out = []
    for s in np.asarray(source_dirs, float).reshape(-1, 3):
        try:
            az, el = model_aim(kin, model, s, aim_point)
        except (LimitError, ValueError):
            continue

        def beam(v: np.ndarray, s=s, az=az, el=el) -> np.ndarray:
            m = TrackingModel(v)
            rot = poses(kin, m, [(az, el)])[0]
            n = rot @ BODY_NORMAL
            center = kin.position + m.position_offset() + rot @ kin.concentrator_translation
            return 2.0 * float(s @ n) * n - s - unit(aim_point - center)

        out.append(jacobian(beam, model.values, np.full(len(model.values), _STEP)))
    return np.stack(out) if out else np.empty((0, 3, len(model.values)))


def posterior(cov: np.ndarray, h: np.ndarray, noise_rad: float) -> np.ndarray:
    """Σ' of Eq. (1) after observing ``h`` (m × p) with independent noise ``noise_rad``."""
    s = noise_rad**2 * np.eye(len(h)) + h @ cov @ h.T
    k = cov @ h.T @ np.linalg.inv(s)
    out = cov - k @ h @ cov
    return 0.5 * (out + out.T)


def daytime_variance(a: np.ndarray, cov: np.ndarray) -> float:
    """V of Eq. (2), rad², for beam Jacobians ``a`` (k, 3, p); NaN without any."""
    if not len(a):
        return float("nan")
    return float(np.einsum("kip,pq,kiq->", a, cov, a) / len(a))


@dataclass(frozen=True)
class Pick:
    """One chosen candidate: its index, the expected daytime RMS before and after it (mrad,
    sqrt of Eq. 2) and the gain (rad² of Eq. 2)."""

    index: int
    rms_before_mrad: float
    rms_after_mrad: float
    gain: float


def _pick(index: int, v_before: float, v_after: float) -> Pick:
    return Pick(index, 1e3 * float(np.sqrt(max(v_before, 0.0))), 1e3 * float(np.sqrt(max(v_after, 0.0))),
                v_before - v_after)


def greedy_design(cov: np.ndarray, candidates: Sequence[np.ndarray], a: np.ndarray, noise_rad: float,
                  n: int) -> tuple[list[Pick], np.ndarray]:
    """Pick up to ``n`` of ``candidates`` (each an H of Eq. 1) by greatest gain, updating Σ after
    each, each candidate at most once (a repeat only averages noise; a new geometry separates
    terms); returns the picks and the final covariance."""
    picks: list[Pick] = []
    used: set[int] = set()
    v = daytime_variance(a, cov)
    for _ in range(min(n, len(candidates))):
        best = None
        for i, h in enumerate(candidates):
            if i in used:
                continue
            c = posterior(cov, h, noise_rad)
            vi = daytime_variance(a, c)
            if best is None or vi < best[1]:
                best = (i, vi, c)
        i, vi, cov = best
        used.add(i)
        picks.append(_pick(i, v, vi))
        v = vi
    return picks, cov


def fixed_design(cov: np.ndarray, candidates: Sequence[np.ndarray], a: np.ndarray, noise_rad: float,
                 order: Sequence[int]) -> tuple[list[Pick], np.ndarray]:
    """The candidates of ``order`` taken as they come (a schedule that does not look at the
    gain), scored like :func:`greedy_design`."""
    picks: list[Pick] = []
    v = daytime_variance(a, cov)
    for i in order:
        cov = posterior(cov, candidates[i], noise_rad)
        vi = daytime_variance(a, cov)
        picks.append(_pick(i, v, vi))
        v = vi
    return picks, cov
