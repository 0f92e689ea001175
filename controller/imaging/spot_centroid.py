"""The beam's full energy centroid over a background surface fitted around the spot.

Starting from the presence decision's candidate spot (:mod:`controller.imaging.presence`):

1. **Background**: a quadratic surface b(x, y) (:class:`controller.imaging.background.Background`)
   fitted by sigma-clipped least squares (3 σ, 3 rounds) to the ring of the analysis level
   between ``RING`` = (0.5, 1.5) footprint radii r = √(area/π) outside the half-peak footprint:
   close enough to follow shading and vignetting across the spot, outside the spot's core.
2. **Window**: the ellipse q(x − c) = (x − c)ᵀ C⁻¹ (x − c) ≤ ``WINDOW``², C the covariance of
   the footprint weighted by the smoothed excess, centred on the current estimate c.
3. **Centroid**: c ← Σ_W s·x / Σ_W s with s = I − b over the window W, every pixel counted
   (negative residuals too: no threshold truncates the tails), repeated until c moves less
   than 0.01 px (at most ``ITERATIONS`` times). Because the window is point-symmetric about c,
   a constant error of b does not move c; only its slope across the window does.

Reported, not averaged in: the view's edges the window crosses (``clipped``: the spot runs
out of the view, its centroid is biased inwards) and a second spot: the largest smoothed
excess outside the window grown by half, if it is itself a beam by the presence statistic and
holds at least ``SECOND_FRACTION`` of the main spot's smoothed peak.

Conventions: x = column, y = row, full-resolution pixels, pixel centres at integers.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from controller.imaging.background import Background
from controller.imaging.presence import Presence

RING = (0.5, 1.5)  # inner, outer distance of the background ring from the footprint, in r
WINDOW = 3.0  # the window's half-size in units of the footprint's standard deviation
ITERATIONS = 12
SECOND_FRACTION = 0.25  # of the main spot's smoothed peak, for a second spot to be reported
_CLIP_SIGMA = 3.0


@dataclass(frozen=True)
class SpotCentroid:
    """``x``, ``y``: energy centroid (px); ``total``: Σ s over the window (image units);
    ``background``: the fitted surface; ``window``: (row0, row1, col0, col1) of the window's
    bounding box inside the view (half-open); ``clipped``: view edges the window crosses;
    ``second_spot``: (x, y) px of another beam-like spot in view, or None."""

    x: float
    y: float
    total: float
    background: Background
    window: tuple[int, int, int, int]
    clipped: tuple[str, ...]
    second_spot: tuple[float, float] | None


def _surface(level_img: np.ndarray, ring: np.ndarray, scale: int, centre: tuple[float, float],
             length: float, fallback: Background) -> Background:
    """Sigma-clipped least-squares quadratic through the ``ring`` pixels of the level image, as a
    full-resolution :class:`Background` about ``centre`` (coordinates scaled by ``length``)."""
    ys, xs = np.nonzero(ring)
    if ys.size > 4096:  # a quadratic has 6 unknowns: a few thousand samples are plenty
        pick = np.linspace(0, ys.size - 1, 4096).astype(np.int64)
        ys, xs = ys[pick], xs[pick]
    if ys.size < 24:
        return fallback
    v = level_img[ys, xs].astype(np.float64)
    u = (xs * scale - centre[0]) / length
    w = (ys * scale - centre[1]) / length
    a = np.stack([np.ones_like(u), u, w, u * u, w * w, u * w], axis=1)
    use = np.ones(v.size, bool)
    coef = np.zeros(6)
    sigma = 0.0
    for _ in range(3):
        au = a[use]
        coef = np.linalg.solve(au.T @ au + 1e-9 * np.eye(6), au.T @ v[use])
        res = v - a @ coef
        r_use = res[use]
        sigma = 1.4826 * float(np.median(np.abs(r_use - np.median(r_use))))
        keep = np.abs(res) <= max(_CLIP_SIGMA * sigma, 1e-9)
        if keep.sum() < 24:
            break
        use = keep
    sx, sy = coef[1] / length, coef[2] / length
    return Background(level=float(coef[0] - sx * centre[0] - sy * centre[1]), slope_x=float(sx),
                      slope_y=float(sy), noise=sigma,
                      quad=tuple(float(c / length**2) for c in coef[3:]),
                      centre=(float(centre[0]), float(centre[1])))


def _ellipse_q(cinv: np.ndarray, xs: np.ndarray, ys: np.ndarray, cx: float, cy: float) -> np.ndarray:
    """q = dᵀ C⁻¹ d over the grid of columns ``xs`` and rows ``ys`` (rows, cols)."""
    u = (xs - cx)[None, :]
    v = (ys - cy)[:, None]
    return cinv[0, 0] * u * u + 2.0 * cinv[0, 1] * u * v + cinv[1, 1] * v * v


def spot_centroid(image: np.ndarray, presence: Presence, mask: np.ndarray | None = None) -> SpotCentroid:
    """Full energy centroid of the spot ``presence`` found in ``image`` (see the module doc).
    ``mask``: optional bool target mask (rows, cols); off-target pixels weigh nothing."""
    img = np.asarray(image)
    rows, cols = img.shape
    k = presence.level
    fp = presence.footprint
    g = presence.smoothed
    fy, fx = np.nonzero(fp)
    wt = np.maximum(g[fy, fx] - presence.floor, 0.0).astype(np.float64)
    if not wt.sum() > 0:
        wt = np.ones(fy.size)
    cx = float((wt * fx).sum() / wt.sum()) * k
    cy = float((wt * fy).sum() / wt.sum()) * k
    cov = np.cov(np.stack([fx * k, fy * k]).astype(np.float64), aweights=wt) if fy.size > 2 else np.eye(2)
    cov = cov + np.eye(2) * (0.25 * k * k + 1.0)  # at least a pixel wide
    cinv = np.linalg.inv(cov)
    r_eq = float(np.sqrt(fy.size / np.pi))
    dist = cv2.distanceTransform((~fp).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    ring = (dist > RING[0] * r_eq) & (dist <= RING[1] * r_eq) & presence.target
    bg = _surface(presence.level_image, ring, k, (cx, cy), max(r_eq * k, 1.0), presence.background)
    # The window's bounding box at the start, with room for the centre to move.
    hx = WINDOW * float(np.sqrt(cov[0, 0])) + 2 + k
    hy = WINDOW * float(np.sqrt(cov[1, 1])) + 2 + k
    x0, x1 = int(np.floor(cx - 1.5 * hx)), int(np.ceil(cx + 1.5 * hx)) + 1
    y0, y1 = int(np.floor(cy - 1.5 * hy)), int(np.ceil(cy + 1.5 * hy)) + 1
    c0, c1, r0, r1 = max(0, x0), min(cols, x1), max(0, y0), min(rows, y1)
    s = np.asarray(img[r0:r1, c0:c1], dtype=np.float64) - bg.evaluate((r1 - r0, c1 - c0), origin=(r0, c0))
    if mask is not None:
        s = np.where(np.asarray(mask[r0:r1, c0:c1], bool), s, 0.0)
    xs = np.arange(c0, c1, dtype=np.float64)
    ys = np.arange(r0, r1, dtype=np.float64)
    total = 0.0
    inside = np.zeros(s.shape, bool)
    for _ in range(ITERATIONS):
        inside = _ellipse_q(cinv, xs, ys, cx, cy) <= WINDOW * WINDOW
        w = np.where(inside, s, 0.0)
        total = float(w.sum())
        if not total > 0.0:
            break
        nx = float(w.sum(axis=0) @ xs) / total
        ny = float(w.sum(axis=1) @ ys) / total
        moved = np.hypot(nx - cx, ny - cy)
        cx, cy = nx, ny
        if moved < 0.01:
            break
    clipped = tuple(edge for edge, out in (("top", cy - hy < 0), ("bottom", cy + hy > rows - 1),
                                           ("left", cx - hx < 0), ("right", cx + hx > cols - 1)) if out)
    return SpotCentroid(x=cx, y=cy, total=total, background=bg, window=(r0, r1, c0, c1), clipped=clipped,
                        second_spot=_second_spot(presence, cinv, (cx, cy)))


def _second_spot(p: Presence, cinv: np.ndarray, centre: tuple[float, float]) -> tuple[float, float] | None:
    """(x, y) px of the largest smoothed excess outside the main window grown by half, when it
    is a beam by itself (presence statistic ≥ threshold) and ≥ SECOND_FRACTION of the main peak."""
    k = p.level
    g = p.smoothed
    xs = np.arange(g.shape[1], dtype=np.float64) * k
    ys = np.arange(g.shape[0], dtype=np.float64) * k
    away = (_ellipse_q(cinv, xs, ys, *centre) > (1.5 * WINDOW) ** 2) & p.target & ~p.footprint
    if not away.any():
        return None
    at = np.unravel_index(int(np.argmax(np.where(away, g, -np.inf))), g.shape)
    excess = float(g[at]) - p.floor
    main = p.statistic * p.spread
    if p.spread > 0 and excess / p.spread >= p.threshold and excess >= SECOND_FRACTION * main:
        return float(at[1] * k), float(at[0] * k)
    return None
