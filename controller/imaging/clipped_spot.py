"""Where the centre of a beam spot clipped by the camera view's edge lies, from its visible part.

The energy centroid of a clipped spot is biased towards the inside of the view: the part beyond
the edge is missing. A move on that centroid falls short, and the next look is clipped again or
far off the aim. A spot is (about) symmetric about its centre, so its centre is read from its
half-maximum contour instead of its energy (σ-smoothed image, level = half its visible maximum):

* only the faint tails clipped (the half-maximum contour is in view along every clipped axis:
  both crossings of the axis profile, the above-threshold signal summed over the other axis):
  the midpoint of the two crossings on each clipped axis, exact for a symmetric profile,
  confidence 1;
* the spot's core clipped: an ellipse fitted (least squares, ``cv2.fitEllipse``) to the
  contour's points away from the clipped edges gives the centre on the clipped axes; confidence
  0.5, or 0.25 when even the maximum lies on the edge (the centre itself beyond it: the visible
  maximum underestimates the peak, so the contour is too wide and the centre a rough guess) or
  when the fitted ellipse, cut by the view, does not cover the visible core (intersection over
  union < ``MIN_COVER``: two lobes, an angular spot);
* clipped on both sides of an axis, or fewer than ``MIN_POINTS`` contour points in view: no
  estimate.

Bounds (the estimate is moved to, never trusted further): on a clipped axis the centre lies
between the visible centroid (the bias is outward only) and the visible spot's extent along the
edge beyond it (no spot here is more than that elongated); an axis not clipped keeps the
centroid. Image convention: x = column, y = row, pixel centres at integer coordinates; the
result is in pixels and may lie outside the view.
"""

from __future__ import annotations

import cv2
import numpy as np

CORE_CUT = 0.5  # confidence of an ellipse-fitted centre whose maximum is in view
BEYOND = 0.25  # ... whose maximum lies on the clipped edge
MIN_POINTS = 8  # contour points in view that an ellipse is fitted to
MIN_COVER = 0.85  # intersection over union of the fitted ellipse (in view) and the visible core
SMOOTH_PX = 2.0  # σ of the smoothing before the half-maximum contour (noise, not shape)
_AXES = (("left", "right"), ("top", "bottom"))  # x (columns), y (rows)


def _crossings(p: np.ndarray) -> tuple[float | None, float | None]:
    """Sub-pixel positions where ``p`` rises to and falls from half its maximum (None: at the edge)."""
    h = 0.5 * float(p.max())
    idx = np.flatnonzero(p >= h)
    first, last = int(idx[0]), int(idx[-1])

    def cross(i: int, j: int) -> float:
        # Linear between the pixel centres i (below h) and j (at or above h).
        return i + (h - p[i]) / (p[j] - p[i]) * (j - i)

    lo = cross(first - 1, first) if first > 0 else None
    hi = cross(last + 1, last) if last < p.size - 1 else None
    return lo, hi


def _ellipse_centre(smooth: np.ndarray, clipped: tuple[str, ...]) -> tuple[tuple[float, float], float] | None:
    """Centre of the ellipse fitted to the half-maximum contour's points off the clipped edges,
    and how well the fitted ellipse, cut by the view, covers the visible core (intersection over
    union of the two masks: a two-lobed or angular core fits no ellipse)."""
    core = (smooth > 0.5 * float(smooth.max())).astype(np.uint8)
    contours, _ = cv2.findContours(core, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    pts = max(contours, key=cv2.contourArea)[:, 0, :]
    rows, cols = smooth.shape
    keep = np.ones(len(pts), bool)
    for edge, axis, limit in (("left", 0, 0), ("right", 0, cols - 1), ("top", 1, 0), ("bottom", 1, rows - 1)):
        if edge in clipped:  # a contour point on the edge is where the view ends, not the spot
            keep &= np.abs(pts[:, axis] - limit) > 1
    if keep.sum() < MIN_POINTS:
        return None
    box = cv2.fitEllipse(pts[keep].astype(np.float32))
    (cx, cy), (da, db), _ = box
    if not all(np.isfinite(v) for v in (cx, cy, da, db)) or max(da, db) > 4 * max(rows, cols):
        return None
    fitted = np.zeros_like(core)
    cv2.ellipse(fitted, box, 1, thickness=-1)
    union = int(np.count_nonzero(fitted | core))
    return (float(cx), float(cy)), (int(np.count_nonzero(fitted & core)) / union if union else 0.0)


def clipped_centre(signal: np.ndarray, rel_threshold: float, clipped: tuple[str, ...],
                   centroid_xy: tuple[float, float]) -> tuple[tuple[float, float] | None, float]:
    """((x, y) px, confidence) of the centre of a spot clipped at the view's ``clipped`` edges
    ("top", "bottom", "left", "right"); (None, 0.0) when it cannot be told (see module doc).

    ``signal``: background-free image; the spot is where its copy smoothed with σ = ``SMOOTH_PX``
    exceeds ``rel_threshold`` × its maximum (the energy centroid ``centroid_xy`` used the same
    threshold)."""
    s = np.asarray(signal, dtype=np.float32)
    smooth = cv2.GaussianBlur(s, (0, 0), SMOOTH_PX)
    mask = smooth > rel_threshold * float(smooth.max())
    if not mask.any() or not float(np.where(mask, s, 0.0).sum()) > 0:
        return None, 0.0
    cut = [k for k, (lo, hi) in enumerate(_AXES) if lo in clipped or hi in clipped]
    if any(lo in clipped and hi in clipped for lo, hi in _AXES):
        return None, 0.0
    w = np.where(mask, s, 0.0).astype(np.float64)
    profiles = (w.sum(axis=0), w.sum(axis=1))
    tails = [_crossings(profiles[k]) for k in cut]
    if all(lo is not None and hi is not None for lo, hi in tails):
        centre, conf = list(centroid_xy), 1.0
        for k, (lo, hi) in zip(cut, tails, strict=True):
            centre[k] = 0.5 * (lo + hi)
    else:
        fit = _ellipse_centre(smooth, clipped)
        if fit is None:
            return None, 0.0
        (fx, fy), cover = fit
        centre = list(centroid_xy)
        for k in cut:
            centre[k] = (fx, fy)[k]
        iy, ix = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
        on_edge = any((lo in clipped and pos <= 1) or (hi in clipped and pos >= n - 2)
                      for (lo, hi), pos, n in zip(_AXES, (ix, iy), (s.shape[1], s.shape[0]), strict=True))
        conf = BEYOND if on_edge or cover < MIN_COVER else CORE_CUT
    ys, xs = np.nonzero(mask)
    along_edge = (np.ptp(ys) + 1.0, np.ptp(xs) + 1.0)  # for x: the extent in rows; for y: in columns
    for k in cut:
        outward = 1.0 if _AXES[k][1] in clipped else -1.0
        beyond = outward * (centre[k] - centroid_xy[k])
        centre[k] = float(centroid_xy[k] + outward * np.clip(beyond, 0.0, along_edge[k]))
    return (float(centre[0]), float(centre[1])), conf
