"""Experimental design for the tracking model: which geometry to measure next.

A measurement at motor steps (s_az, s_el) observes the two tangential components of the
mirror normal n(p) (:mod:`controller.geometry.model.fit`, Eq. 1) with noise σ_n, so with
H = ∂(t₁·n, t₂·n)/∂p (2 × p) the posterior covariance of the model terms becomes

    Σ' = Σ − Σ Hᵀ (σ_n² I + H Σ Hᵀ)⁻¹ H Σ                                  (1)

(the Kalman / Woodbury update of a linear-Gaussian observation). What calibration is for is
the daytime pointing: with A_k = ∂r_k/∂p the Jacobian of the reflected beam at sun position
k (the heliostat aiming with the model), the expected squared daytime error is

    V(Σ) = mean_k tr(A_k Σ A_kᵀ)                                            (2)

and a candidate's *gain* is V(Σ) − V(Σ'), the expected-variance reduction (an A-optimal
design weighted by the daytime geometry [1]). With M = mean_k A_kᵀ A_k (p × p) it is

    V(Σ) = tr(Σ M),                                                         (3)

so the sun positions are summed once per heliostat and every candidate's Σ' is scored by one
trace. :func:`greedy_design` picks candidates one at a time by gain, updating Σ after each
pick, which is within (1 − 1/e) of the best set for this submodular objective [2].

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

from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import STEP_SI, aim_steps, forward_jacobian, normal_and_center, perturbed
from controller.geometry.vectors import cross, unit


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


_STEP = STEP_SI  # rad or m: well inside the linear range of every term, far above rounding


def normal_jacobians(kin: HeliostatKinematics, model: TrackingModel, steps: np.ndarray, spots: np.ndarray,
                     source_dirs=None, source_pos=None) -> np.ndarray:
    """H of Eq. (1) for K measurements at once, (K, 2, p): spots expected at ``spots`` (K, 3)
    m ENU at motor ``steps`` (K, 2), under sources at ``source_dirs`` (K, 3; the sun) or the
    lamps at ``source_pos`` (K, 3) or (3,) m ENU — :func:`normal_jacobian` for each."""
    steps = np.asarray(steps, float).reshape(-1, 2)
    spots = np.asarray(spots, float).reshape(-1, 3)
    vals = perturbed(model.values)[:, None, :]  # (p + 1, 1, p)
    n, c = normal_and_center(kin, vals, steps)  # (p + 1, K, 3)
    base = tangents_batch(n[0])  # (K, 2, 3)
    src = unit(np.asarray(source_pos, float) - c) if source_pos is not None else \
        np.broadcast_to(unit(np.asarray(source_dirs, float)), c.shape)
    implied = unit(src + unit(spots - c))
    obs = np.einsum("kij,pkj->pki", base, n - implied)  # (p + 1, K, 2)
    return forward_jacobian(obs)


def normal_jacobian(kin: HeliostatKinematics, model: TrackingModel, az_steps: float, el_steps: float,
                    source_dir, spot, source_pos=None) -> np.ndarray:
    """H of Eq. (1) for a spot expected at ``spot`` (m ENU) under a source at ``source_dir``
    (the sun) or ``source_pos`` (a lamp, m ENU): ∂(t₁·(n − m), t₂·(n − m))/∂p at the given
    steps, with m the normal the spot implies (it moves with the position terms), (2, p), per
    SI unit of each term."""
    sun = None if source_dir is None else np.asarray(source_dir, float)[None]
    return normal_jacobians(kin, model, np.array([[az_steps, el_steps]], float),
                            np.asarray(spot, float)[None], sun, source_pos)[0]


def tangents_batch(n: np.ndarray) -> np.ndarray:
    """:func:`tangents` of each unit vector of ``n`` (K, 3): (K, 2, 3)."""
    n = np.asarray(n, float)
    helper = np.where((np.abs(n[..., 2]) < 0.9)[..., None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    t1 = unit(cross(helper, n))
    return np.stack([t1, cross(n, t1)], axis=-2)


def beam_jacobians(kin: HeliostatKinematics, model: TrackingModel, source_dirs: np.ndarray,
                   aim_point) -> np.ndarray:
    """A_k of Eq. (2), (k, 3, p): the sensitivity to the terms of the reflected beam's error —
    the beam r = 2(s·n)n − s less the direction from the mirror centre to ``aim_point`` (m ENU),
    which the position terms move — at the steps the model aims with for each reachable source
    direction (unit ENU, towards the source). Unreachable directions are left out (k may be 0)."""
    s = np.asarray(source_dirs, float).reshape(-1, 3)
    aim_point = np.asarray(aim_point, float)
    if not len(s):
        return np.empty((0, 3, len(model.values)))
    steps, ok = aim_steps(kin, model.values, np.broadcast_to(aim_point, s.shape), source_dirs=s)
    if not ok.any():
        return np.empty((0, 3, len(model.values)))
    s, steps = s[ok], steps[ok]
    n, c = normal_and_center(kin, perturbed(model.values)[:, None, :], steps)  # (p + 1, k, 3)
    beam = 2.0 * np.sum(s * n, axis=-1, keepdims=True) * n - s - unit(aim_point - c)
    return forward_jacobian(beam)


def daytime_weight(a: np.ndarray) -> np.ndarray:
    """M of Eq. (3), (p, p): V(Σ) of Eq. (2) is tr(Σ M); NaN without any A_k."""
    if not len(a):
        return np.full((a.shape[-1],) * 2, np.nan)
    return np.einsum("kip,kiq->pq", a, a) / len(a)


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


def posteriors(cov: np.ndarray, h: np.ndarray, noise_rad: float) -> np.ndarray:
    """Σ' of Eq. (1) for each of C candidate observations ``h`` (C, m, p) at once: (C, p, p)."""
    hc = h @ cov  # (C, m, p)
    s = noise_rad**2 * np.eye(h.shape[1]) + hc @ np.swapaxes(h, -1, -2)
    out = cov - np.swapaxes(hc, -1, -2) @ np.linalg.solve(s, hc)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def greedy_design(cov: np.ndarray, candidates: Sequence[np.ndarray], a: np.ndarray, noise_rad: float,
                  n: int, weight: np.ndarray | None = None) -> tuple[list[Pick], np.ndarray]:
    """Pick up to ``n`` of ``candidates`` (each an H of Eq. 1) by greatest gain, updating Σ after
    each, each candidate at most once (a repeat only averages noise; a new geometry separates
    terms); returns the picks and the final covariance. Every candidate's posterior is
    evaluated at once (:func:`posteriors`) and V(Σ') = tr(Σ' M) (:func:`daytime_weight`;
    ``weight``: M when already known)."""
    m = daytime_weight(a) if weight is None else weight
    h = np.asarray(candidates, float).reshape(len(candidates), -1, cov.shape[0])
    picks: list[Pick] = []
    free = np.ones(len(h), bool)
    v = float(np.sum(cov * m))
    for _ in range(min(n, len(h))):
        after = posteriors(cov, h, noise_rad)
        vs = np.einsum("cpq,qp->c", after, m)
        vs = np.where(free & ~np.isnan(vs), vs, np.inf)
        i = int(np.argmin(vs)) if np.isfinite(vs).any() else int(np.flatnonzero(free)[0])
        free[i] = False
        cov, vi = after[i], float(np.sum(after[i] * m))
        picks.append(_pick(i, v, vi))
        v = vi
    return picks, cov


def fixed_design(cov: np.ndarray, candidates: Sequence[np.ndarray], a: np.ndarray, noise_rad: float,
                 order: Sequence[int], weight: np.ndarray | None = None) -> tuple[list[Pick], np.ndarray]:
    """The candidates of ``order`` taken as they come (a schedule that does not look at the
    gain), scored like :func:`greedy_design`."""
    m = daytime_weight(a) if weight is None else weight
    picks: list[Pick] = []
    v = float(np.sum(cov * m))
    for i in order:
        cov = posterior(cov, np.asarray(candidates[i], float), noise_rad)
        vi = float(np.sum(cov * m))
        picks.append(_pick(i, v, vi))
        v = vi
    return picks, cov
