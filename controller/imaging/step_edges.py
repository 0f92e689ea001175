"""Straight shadow steps in the background around a spot: found, tested, and fitted.

A low sun (grazing the north-facing target) casts the shadows of the tower's structure onto
it: straight edges, a few pixels wide, across which the target's brightness jumps. When one
crosses the spot, no smooth surface fitted to a ring around the spot predicts the background
under it, and the energy centroid is pulled towards the bright side. The background around the
spot (:mod:`controller.imaging.spot_centroid`) is therefore

    b(x, y) = quadratic(x, y) + Σ_k h_k · [n_k · (x, y) > d_k]                             (E1)

with up to ``MAX_STEPS`` straight steps (unit normal n_k, offset d_k in px, height h_k in
counts). Each round:

1. **Candidates** (a Hough transform of the gradient): the ring's level image, its dark grid
   lines and fiducial dots removed by a grey closing (``CLOSE_PX`` square; a step edge is kept),
   Sobel gradient; the ring pixels with the strongest gradients (top ``VOTER_FRACTION``) vote
   with their signed magnitude for the line (θ = gradient direction mod π, d = n · (x, y)) in
   ``ANGLE_BIN`` × ``OFFSET_BIN`` cells; the ``CANDIDATES`` largest |sums| (3 × 3 smoothed,
   neighbours suppressed), each refined by a weighted total-least-squares line through its voters.
2. **Test**: for each candidate, the quadratic (+ the steps kept so far) + this step is fitted
   to the ring's samples by sigma-clipped least squares; h is its step height and σ' the robust
   σ of the residuals. The local jump j (mean of the closed image minus the current model in a
   band ``BAND_PX`` wide on either side of the line, on the ring) must agree with h
   (same sign, 0.5 ≤ h / j ≤ 2: a sharp edge, not a smooth lobe the step happens to absorb),
   and σ' ≤ ``KEEP_SIGMA`` σ (the step explains a real part of the ring's variation).
   The candidate with the smallest σ' is kept; none passing ends the search.

The thresholds were chosen on real empty-target photos with real spots laid on them (the
tuning split of ``tests/data/real/utis-empty``), without and with synthetic straight steps
(docs/imaging.md, "Shadow steps under the spot"); a smooth target yields no step.

Conventions: x = column, y = row; full-resolution pixels in results, the ring's samples at the
analysis level (a level pixel (x, y) is the full-resolution pixel (k x, k y)).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

MAX_STEPS = 2
CANDIDATES = 8
CLOSE_PX = 7  # the grey closing's side, level px: wider than the target's grid lines (≈ 3 px)
VOTER_FRACTION = 0.05  # of the ring's pixels, those with the strongest gradients, vote
ANGLE_BIN = np.pi / 60  # 3°
OFFSET_BIN = 2.0  # level px
BAND_PX = 4.0  # the local jump's band on either side of the line, level px
KEEP_SIGMA = 0.9  # a step is kept when it brings the ring's robust σ to at most this fraction
_CLIP_SIGMA = 3.0


@dataclass(frozen=True)
class Step:
    """b += ``height`` where ``nx`` x + ``ny`` y > ``d`` (full-resolution px, counts)."""

    nx: float
    ny: float
    d: float
    height: float

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The step's contribution at the points (``x``, ``y``) (px), in their dtype."""
        return np.where(self.nx * x + self.ny * y > self.d, self.height, 0.0).astype(x.dtype, copy=False)


def robust_fit(a: np.ndarray, v: np.ndarray, use: np.ndarray | None = None, rounds: int = 3
               ) -> tuple[np.ndarray, float, np.ndarray]:
    """Sigma-clipped least squares v ≈ a @ coef: ``rounds`` times, fit to the kept samples
    (all, or ``use`` at the start), σ = 1.4826 MAD of their residuals, keep |residual| ≤ 3 σ.
    Returns (coef, σ, kept)."""
    use = np.ones(v.size, bool) if use is None else use
    k = a.shape[1]
    coef = np.zeros(k)
    sigma = 0.0
    for _ in range(rounds):
        au = a[use]
        coef = np.linalg.solve(au.T @ au + 1e-9 * np.eye(k), au.T @ v[use])
        res = v - a @ coef
        r_use = res[use]
        sigma = 1.4826 * float(np.median(np.abs(r_use - np.median(r_use))))
        keep = np.abs(res) <= max(_CLIP_SIGMA * sigma, 1e-9)
        if keep.sum() < 24:
            break
        use = keep
    return coef, sigma, use


def _line_through(px: np.ndarray, py: np.ndarray, w: np.ndarray, th0: float) -> tuple[float, float]:
    """(θ, d) of the weighted total-least-squares line through the points, its normal on the
    side of the angle ``th0``."""
    sw = float(w.sum())
    mx, my = float(w @ px) / sw, float(w @ py) / sw
    dx, dy = px - mx, py - my
    cxx, cyy, cxy = float(w @ (dx * dx)), float(w @ (dy * dy)), float(w @ (dx * dy))
    th = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy) + 0.5 * np.pi  # the normal of the principal axis
    if np.cos(th - th0) < 0.0:
        th -= np.pi
    return float(th), float(mx * np.cos(th) + my * np.sin(th))


def _candidates(closed: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> list[tuple[float, float]]:
    """(θ, d) of the strongest straight edges of ``closed`` on the ring pixels (``ys``, ``xs``)
    of that window; d in the window's pixels: normal (cos θ, sin θ), edge where n · (x, y) = d."""
    if ys.size < 64:
        return []
    gx = cv2.Sobel(closed, cv2.CV_32F, 1, 0, ksize=3)[ys, xs]
    gy = cv2.Sobel(closed, cv2.CV_32F, 0, 1, ksize=3)[ys, xs]
    mag = np.hypot(gx, gy)
    rank = int((1.0 - VOTER_FRACTION) * (mag.size - 1))
    top = mag > np.partition(mag, rank)[rank]
    if top.sum() < 16:
        return []
    px, py, mag = xs[top].astype(np.float64), ys[top].astype(np.float64), mag[top].astype(np.float64)
    theta = np.arctan2(gy[top], gx[top]).astype(np.float64)
    sign = np.where(theta < 0.0, -1.0, 1.0)
    theta = np.where(theta < 0.0, theta + np.pi, theta)
    d = px * np.cos(theta) + py * np.sin(theta)
    n_a = int(round(np.pi / ANGLE_BIN))
    d_max = float(np.hypot(*closed.shape)) + 1.0
    n_d = int(np.ceil(2.0 * d_max / OFFSET_BIN)) + 1
    cell = (np.minimum((theta / ANGLE_BIN).astype(np.int64), n_a - 1) * n_d
            + ((d + d_max) / OFFSET_BIN).astype(np.int64))
    acc = np.bincount(cell, weights=sign * mag, minlength=n_a * n_d).reshape(n_a, n_d)
    acc = np.abs(cv2.blur(acc.astype(np.float32), (3, 3)))
    out = []
    for _ in range(CANDIDATES):
        i, j = np.unravel_index(int(np.argmax(acc)), acc.shape)
        if not acc[i, j] > 0.0:
            break
        acc[max(0, i - 3):i + 4, max(0, j - 3):j + 4] = 0.0
        th0, d0 = (i + 0.5) * ANGLE_BIN, (j + 0.5) * OFFSET_BIN - d_max
        near = (np.abs(theta - th0) < 2 * ANGLE_BIN) & (np.abs(d - d0) < 1.5 * OFFSET_BIN)
        out.append(_line_through(px[near], py[near], mag[near], th0) if near.sum() >= 8 else (th0, d0))
    return out


def fit_steps(level_img: np.ndarray, ring: tuple[np.ndarray, np.ndarray, tuple[int, int]],
              origin: tuple[int, int], scale: int,
              quadratic: Callable[[np.ndarray, np.ndarray], np.ndarray], sx: np.ndarray, sy: np.ndarray,
              v: np.ndarray, fit: tuple[np.ndarray, float, np.ndarray]
              ) -> tuple[tuple[Step, ...], np.ndarray, float]:
    """Steps of (E1) for the ring samples (module doc): ``level_img`` the analysis level,
    ``ring`` the rows and columns of the ring's pixels in a window of it of shape ``ring[2]``
    whose top-left pixel is ``origin`` (row, col); ``quadratic``
    the design of the quadratic at full-resolution points (x, y) → (n, 6); the samples at
    full-resolution ``sx``, ``sy`` with values ``v``; ``fit`` the quadratic's (coefficients,
    robust σ, kept samples) without steps. Returns the kept steps, the quadratic's
    coefficients fitted with them, and the robust σ of that fit."""
    ry, rx, (h, w) = ring
    win = np.asarray(level_img[origin[0]:origin[0] + h, origin[1]:origin[1] + w], np.float32)
    closed = cv2.morphologyEx(win, cv2.MORPH_CLOSE, np.ones((CLOSE_PX, CLOSE_PX), np.uint8))
    # The candidates as full-resolution lines n · (x, y) = d.
    lines = [(np.cos(th), np.sin(th), (d + np.cos(th) * origin[1] + np.sin(th) * origin[0]) * scale)
             for th, d in _candidates(closed, ry, rx)]
    rxf = (rx + origin[1]).astype(np.float64) * scale
    ryf = (ry + origin[0]).astype(np.float64) * scale
    design = quadratic(sx, sy)
    coef, current, use = fit
    steps: list[Step] = []
    band = BAND_PX * scale
    ring_px = (rx, ry, rxf, ryf)
    for _ in range(MAX_STEPS):
        found = None
        for line, col in _screened(lines, design, v, use, sx, sy):
            # Confirm by the full robust fit: σ' and the height, which must match the local jump.
            trial = np.concatenate([design, col[:, None]], 1)
            c_new, s_new, u_new = robust_fit(trial, v)
            if s_new <= KEEP_SIGMA * current and _sharp(line, float(c_new[-1]), closed, ring_px, band,
                                                        quadratic, coef, steps):
                found = (line, trial, c_new, s_new, u_new)
                break
        if found is None:
            break
        line, design, coef, current, use = found
        steps = [Step(st.nx, st.ny, st.d, float(coef[6 + i])) for i, st in enumerate(steps)]
        steps.append(Step(float(line[0]), float(line[1]), float(line[2]), float(coef[-1])))
        lines = [ln for ln in lines if ln is not line]
    return tuple(steps), coef[:6], current


def _screened(lines: list[tuple[float, float, float]], design: np.ndarray, v: np.ndarray, use: np.ndarray,
              sx: np.ndarray, sy: np.ndarray) -> list[tuple[tuple[float, float, float], np.ndarray]]:
    """The candidate ``lines`` whose step column, added to ``design`` and fitted by least
    squares to the kept samples ``use``, lowers their sum of squares to at most KEEP_SIGMA²
    of the current one (an exact rank-one update), best first, at most two: (line, column)."""
    du, vu = design[use], v[use]
    gram = np.linalg.inv(du.T @ du + 1e-9 * np.eye(du.shape[1]))
    res = vu - du @ (gram @ (du.T @ vu))
    sse = float(res @ res)
    ranked = []
    for line in lines:
        col = (line[0] * sx + line[1] * sy > line[2]).astype(np.float64)
        cu = col[use]
        if not 24 <= cu.sum() <= cu.size - 24:
            continue
        b = du.T @ cu
        denom = float(cu @ cu - b @ gram @ b)
        if denom > 1e-9:
            ratio = 1.0 - float(cu @ res) ** 2 / denom / max(sse, 1e-300)
            if ratio <= KEEP_SIGMA:
                ranked.append((ratio, line, col))
    ranked.sort(key=lambda t: t[0])
    return [(line, col) for _, line, col in ranked[:3]]


def _sharp(line: tuple[float, float, float], height: float, closed: np.ndarray,
           ring_px: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], band: float,
           quadratic: Callable[[np.ndarray, np.ndarray], np.ndarray], coef: np.ndarray,
           steps: list[Step]) -> bool:
    """Whether the local jump across ``line`` agrees with the fitted ``height``: mean of the
    closed image minus the current model (``coef`` of the quadratic, ``steps``) on the ring
    pixels within ``band`` (full-resolution px) beyond the line, minus the same before it;
    0.5 ≤ height / jump ≤ 2, at least 8 pixels either side."""
    rx, ry, rxf, ryf = ring_px
    t = line[0] * rxf + line[1] * ryf - line[2]
    near = np.abs(t) <= band
    if not near.any():
        return False
    tn, xn, yn = t[near], rxf[near], ryf[near]
    r = closed[ry[near], rx[near]] - quadratic(xn, yn) @ coef[:6]
    for st in steps:
        r = r - st.at(xn, yn)
    lo, hi = tn < 0.0, tn > 0.0
    if lo.sum() < 8 or hi.sum() < 8:
        return False
    jump = float(r[hi].mean() - r[lo].mean())
    return jump != 0.0 and 0.5 <= height / jump <= 2.0
