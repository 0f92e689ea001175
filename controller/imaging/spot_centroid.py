"""The beam's full energy centroid over a background surface fitted around the spot.

Starting from the presence decision's candidate spot (:mod:`controller.imaging.presence`):

1. **Background**: a quadratic surface b(x, y) (:class:`controller.imaging.background.Background`)
   fitted by sigma-clipped least squares (3 σ, 3 rounds) to the ring of the analysis level
   between ``RING`` = (0.5, 1.5) footprint radii r = √(area/π) outside the half-peak footprint:
   close enough to follow shading and vignetting across the spot, outside the spot's core;
   plus up to two straight shadow steps (E1 of :mod:`controller.imaging.step_edges`) when
   the ring shows sharp straight edges that explain its variation (a low sun casts the
   tower's shadows across the target; no smooth surface predicts them under the spot).
2. **Window**: the ellipse q(x − c) = (x − c)ᵀ C⁻¹ (x − c) ≤ ``WINDOW``², C the covariance of
   the footprint weighted by the smoothed excess, centred on the current estimate c.
3. **Centroid**: c ← Σ_W s·x / Σ_W s with s = I − b (steps included) over the window W, every pixel counted
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
from controller.imaging.step_edges import Step, fit_steps, robust_fit

RING = (0.5, 1.5)  # inner, outer distance of the background ring from the footprint, in r
WINDOW = 4.0  # the window's half-size in units of the footprint's standard deviation
ITERATIONS = 12
SECOND_FRACTION = 0.25  # of the main spot's smoothed peak, for a second spot to be reported


@dataclass(frozen=True)
class SpotCentroid:
    """``x``, ``y``: energy centroid (px); ``total``: Σ s over the window (image units);
    ``background``: the fitted surface; ``window``: (row0, row1, col0, col1) of the window's
    bounding box inside the view (half-open); ``clipped``: view edges the window crosses;
    ``second_spot``: (x, y) px of another beam-like spot in view, or None; ``steps``: the
    straight shadow steps of the background (:mod:`controller.imaging.step_edges`)."""

    x: float
    y: float
    total: float
    background: Background
    window: tuple[int, int, int, int]
    clipped: tuple[str, ...]
    second_spot: tuple[float, float] | None
    steps: tuple[Step, ...] = ()


def _surface(level_img: np.ndarray, ring: np.ndarray, origin: tuple[int, int], scale: int,
             centre: tuple[float, float], length: float, fallback: Background
             ) -> tuple[Background, tuple[Step, ...]]:
    """Sigma-clipped least-squares quadratic through the ``ring`` pixels (a bool window of the
    level image whose top-left pixel is ``origin``, row and column), with the straight steps
    of :func:`controller.imaging.step_edges.fit_steps`, as a full-resolution
    :class:`Background` about ``centre`` (coordinates scaled by ``length``) and its steps."""
    ry, rx = np.nonzero(ring)
    ys, xs = ry, rx
    if ys.size > 2048:  # a quadratic has 6 unknowns: a couple of thousand samples are plenty
        pick = np.linspace(0, ys.size - 1, 2048).astype(np.int64)
        ys, xs = ys[pick], xs[pick]
    ys, xs = ys + origin[0], xs + origin[1]
    if ys.size < 24:
        return fallback, ()
    v = level_img[ys, xs].astype(np.float64)

    def quadratic(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, w = (x - centre[0]) / length, (y - centre[1]) / length
        return np.stack([np.ones_like(u), u, w, u * u, w * w, u * w], axis=1)

    sx, sy = (xs * scale).astype(np.float64), (ys * scale).astype(np.float64)
    steps, coef, sigma = fit_steps(level_img, (ry, rx, ring.shape), origin, scale, quadratic, sx, sy, v,
                                   robust_fit(quadratic(sx, sy), v))
    gx, gy = coef[1] / length, coef[2] / length
    return Background(level=float(coef[0] - gx * centre[0] - gy * centre[1]), slope_x=float(gx),
                      slope_y=float(gy), noise=sigma,
                      quad=tuple(float(c / length**2) for c in coef[3:]),
                      centre=(float(centre[0]), float(centre[1]))), steps


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
    # The ring, on the footprint's bounding box grown by the ring's outer distance only.
    grow = int(np.ceil(RING[1] * r_eq)) + 2
    a0, a1 = max(0, int(fy.min()) - grow), min(g.shape[0], int(fy.max()) + grow + 1)
    b0, b1 = max(0, int(fx.min()) - grow), min(g.shape[1], int(fx.max()) + grow + 1)
    dist = cv2.distanceTransform((~fp[a0:a1, b0:b1]).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_3)
    ring = (dist > RING[0] * r_eq) & (dist <= RING[1] * r_eq) & presence.target[a0:a1, b0:b1]
    bg, steps = _surface(presence.level_image, ring, (a0, b0), k, (cx, cy), max(r_eq * k, 1.0),
                         presence.background)
    # The pixels the window can reach: the window at the start grown by a fifth (room for the
    # centre to move), listed once; the iterations work on that list.
    hx = WINDOW * float(np.sqrt(cov[0, 0])) + 2 + k
    hy = WINDOW * float(np.sqrt(cov[1, 1])) + 2 + k
    x0, x1 = int(np.floor(cx - 1.2 * hx)), int(np.ceil(cx + 1.2 * hx)) + 1
    y0, y1 = int(np.floor(cy - 1.2 * hy)), int(np.ceil(cy + 1.2 * hy)) + 1
    c0, c1, r0, r1 = max(0, x0), min(cols, x1), max(0, y0), min(rows, y1)
    a = cinv.astype(np.float32)
    reach = _ellipse_q(a, np.arange(c0, c1, dtype=np.float32), np.arange(r0, r1, dtype=np.float32),
                       np.float32(cx), np.float32(cy)) <= (1.2 * WINDOW) ** 2
    if mask is not None:
        reach &= np.asarray(mask[r0:r1, c0:c1], bool)
    py, px = np.nonzero(reach)
    xs, ys = (px + c0).astype(np.float32), (py + r0).astype(np.float32)
    s = np.asarray(img[r0:r1, c0:c1], dtype=np.float32)[reach] - bg.at(xs, ys)  # float32; sums in float64
    for step in steps:
        s -= step.at(xs, ys)
    total = 0.0
    for _ in range(ITERATIONS):
        u, v = xs - np.float32(cx), ys - np.float32(cy)
        inside = a[0, 0] * u * u + 2.0 * a[0, 1] * u * v + a[1, 1] * v * v <= WINDOW * WINDOW
        w = s[inside]
        total = float(w.sum(dtype=np.float64))
        if not total > 0.0:
            break
        # Products in float32, sums in float64 (np.dot would call a BLAS for a few thousand values).
        nx = float(np.sum(w * xs[inside], dtype=np.float64)) / total
        ny = float(np.sum(w * ys[inside], dtype=np.float64)) / total
        moved = np.hypot(nx - cx, ny - cy)
        cx, cy = nx, ny
        if moved < 0.01:
            break
    clipped = tuple(edge for edge, out in (("top", cy - hy < 0), ("bottom", cy + hy > rows - 1),
                                           ("left", cx - hx < 0), ("right", cx + hx > cols - 1)) if out)
    return SpotCentroid(x=cx, y=cy, total=total, background=bg, window=(r0, r1, c0, c1), clipped=clipped,
                        second_spot=_second_spot(presence, cinv, (cx, cy)), steps=steps)


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
