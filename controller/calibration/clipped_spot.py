"""Where the centre of a beam spot clipped by the camera view's edge lies, from its visible part.

The energy centroid of a clipped spot is biased towards the inside of the view: the part beyond
the edge is missing. A move on that centroid falls short, the next look is clipped again, and
after ``CLIPPED_LOOKS`` such looks the cycle gives up (``BeamNotFound``). A spot is (about)
symmetric about its centre along each axis, so its centre is read from its half-maximum
contour instead of its energy:

* per axis, the spot's profile p (the above-threshold signal summed over the other axis) and its
  half-maximum crossings lo < hi (linear interpolation between pixel centres);
* both crossings in view (only the faint tails are clipped): centre = (lo + hi) / 2, exact for a
  symmetric profile, confidence 1;
* the crossing on the clipped side beyond the edge (the spot's core is cut): centre =
  far crossing − h, with h the half width at half maximum along the *other* axis (a round
  spot's), confidence 0.5; if even the profile's maximum is at the edge (the centre itself is
  cut off), its half maximum is underestimated, so the far crossing and the centre fall short:
  a lower bound on the distance beyond the edge, confidence 0.25;
* otherwise (clipped on both sides of an axis, or no half width to borrow): no estimate.

The estimate never lies further inside than the visible centroid (the bias is inward only) and
at most one view size beyond the edge. Image convention: x = column, y = row, pixel centres at
integer coordinates; the result is in pixels and may lie outside the view.
"""

from __future__ import annotations

import cv2
import numpy as np

EXTRAPOLATED = 0.5  # confidence of a centre whose clipped half width is borrowed from the other axis
BEYOND = 0.25  # ... and whose profile peaks at the edge: a lower bound


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


def clipped_centre(signal: np.ndarray, rel_threshold: float, clipped: tuple[str, ...],
                   centroid_xy: tuple[float, float],
                   smooth_sigma_px: float = 1.0) -> tuple[tuple[float, float] | None, float]:
    """((x, y) px, confidence) of the centre of a spot clipped at the view's ``clipped`` edges
    ("top", "bottom", "left", "right"); (None, 0.0) when it cannot be told (see module doc).

    ``signal``: background-free image; the spot is where its σ-smoothed copy exceeds
    ``rel_threshold`` × the maximum (the mask of the energy centroid ``centroid_xy``)."""
    s = np.asarray(signal, dtype=np.float32)
    smooth = cv2.GaussianBlur(s, (0, 0), smooth_sigma_px)
    w = np.where(smooth > rel_threshold * float(smooth.max()), s, 0.0).astype(np.float64)
    if not w.sum() > 0:
        return None, 0.0
    axes = (("left", "right", w.sum(axis=0)), ("top", "bottom", w.sum(axis=1)))
    cross = [_crossings(p) for _, _, p in axes]
    half = [None if lo is None or hi is None else 0.5 * (hi - lo) for lo, hi in cross]
    centre, conf = list(centroid_xy), 1.0
    for k, (low_edge, high_edge, p) in enumerate(axes):
        low, high = low_edge in clipped, high_edge in clipped
        if not (low or high):
            continue
        if low and high:
            return None, 0.0
        lo, hi = cross[k]
        if lo is not None and hi is not None:
            c = 0.5 * (lo + hi)
        elif half[1 - k] is not None and (hi if low else lo) is not None:
            c = hi - half[1 - k] if low else lo + half[1 - k]
            at_edge = int(np.argmax(p)) == (0 if low else p.size - 1)
            conf = min(conf, BEYOND if at_edge else EXTRAPOLATED)
        else:
            return None, 0.0
        n = p.size
        # Inward bias only: the centre lies between the visible centroid and one view beyond the edge.
        centre[k] = float(np.clip(c, -n, centroid_xy[k]) if low else np.clip(c, centroid_xy[k], 2 * n - 1))
    return (centre[0], centre[1]), conf
