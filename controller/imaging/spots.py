"""Several beam spots in one image, each in its own slot's window, and whose spot is whose by a
known step (``calibration.beams_per_target`` K > 1, docs/campaigns.md).

**Windows.** Slot i's window is the rectangle of pixels ``windows[i] = (r0, r1, c0, c1)``
(half-open) around its aim point, as large as a spot's reach plus the identity step
(:mod:`controller.calibration.slots`, Eq. 1); the slot layout keeps the windows disjoint.

**Background and noise.** The image is smoothed by a Gaussian of σ = ``SMOOTH_PX`` pixels;
the background b is the median and the noise σ_b 1.4826 × the median absolute deviation of
the smoothed pixels *outside every window* (the lit target away from the spots).

**A spot in a window** when the window's peak smoothed excess over b is above ``SNR`` σ_b.
Its position is the energy centroid of the excess s = I − b over the window's pixels whose
smoothed excess is above ``FLOOR`` of that peak and above 3 σ_b (x = column, y = row).

**Identity by a known step.** Between two captures every heliostat of the capture moved by
its own known step, whose displacement on the target d_i (m, target axes u, v) is predicted
from its model, all distinct. Heliostat i's spot is *confirmed* when its window holds a spot
in both captures and that spot moved with i's step:

    |Δ_i − d_i| < tol,   Δ_i = c_i'' − c_i',   tol = ½ min_{j≠i} |d_i − d_j|       (1)

(with one heliostat, tol = ½ |d_i|: its spot must move at all). Since the d_j are at least
2 tol apart, a Δ_i within tol of d_i is farther than tol from every other d_j: a spot that
moved with another heliostat's step — two heliostats whose spots were exchanged — is never
confirmed. Anything else (a window empty in either capture, a spot that did not move as
predicted) leaves i *unconfirmed*: it is measured again alone
(:mod:`controller.calibration.group`).
"""

from __future__ import annotations

import cv2
import numpy as np

SMOOTH_PX = 2.0
SNR = 8.0
FLOOR = 0.05


def _smooth(img: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(img, (0, 0), SMOOTH_PX)


def _outside(shape: tuple[int, int], windows) -> np.ndarray:
    out = np.ones(shape, bool)
    for r0, r1, c0, c1 in windows:
        out[r0:r1, c0:c1] = False
    return out


def background(hdr: np.ndarray, windows) -> tuple[float, float]:
    """(b, σ_b) of ``hdr`` outside every window (module docstring)."""
    return _level(_smooth(np.asarray(hdr, np.float32)), windows)


def _level(sm: np.ndarray, windows) -> tuple[float, float]:
    """(b, σ_b) of the smoothed image ``sm`` outside every window."""
    out = sm[_outside(sm.shape, windows)]
    if out.size == 0:
        out = sm.ravel()
    b = float(np.median(out))
    return b, max(1.4826 * float(np.median(np.abs(out - b))), 1e-9)


def window_spots(hdr: np.ndarray, windows) -> np.ndarray:
    """The spot of each of the n ``windows`` (r0, r1, c0, c1): its (x, y) px, NaN when the
    window holds none (module docstring): (n, 2)."""
    img = np.asarray(hdr, np.float32)
    sm = _smooth(img)
    b, noise = _level(sm, windows)
    sm -= b
    out = np.full((len(windows), 2), np.nan)
    for k, (r0, r1, c0, c1) in enumerate(windows):
        w, s = sm[r0:r1, c0:c1], img[r0:r1, c0:c1] - b
        if w.size == 0:
            continue
        peak = float(w.max())
        if peak <= SNR * noise:
            continue
        keep = w > max(FLOOR * peak, 3.0 * noise)
        e = np.where(keep, np.clip(s, 0.0, None), 0.0)
        total = float(e.sum())
        if total <= 0:
            continue
        rows, cols = np.indices(w.shape)
        out[k] = (c0 + float((e * cols).sum()) / total, r0 + float((e * rows).sum()) / total)
    return out


def isolate(hdr: np.ndarray, windows, keep: int) -> np.ndarray:
    """``hdr`` with everything outside window ``keep`` replaced by the background level b: the
    other spots and the faint tails they spread beyond their windows, which an energy centroid
    without a threshold would average in."""
    img = np.asarray(hdr, float)
    b, _ = background(img, windows)
    out = np.full_like(img, b)
    r0, r1, c0, c1 = windows[keep]
    out[r0:r1, c0:c1] = img[r0:r1, c0:c1]
    return out


def confirm_by_step(first_m: np.ndarray, second_m: np.ndarray, steps_m: np.ndarray) -> list[bool]:
    """Eq. (1) per heliostat i: ``first_m`` and ``second_m`` (n, 2) m its window's spot in the
    two captures (NaN: none), ``steps_m`` (n, 2) m its predicted displacement."""
    a, b = np.asarray(first_m, float).reshape(-1, 2), np.asarray(second_m, float).reshape(-1, 2)
    d = np.asarray(steps_m, float).reshape(-1, 2)
    n = len(d)
    out = []
    for i in range(n):
        gaps = [np.linalg.norm(d[i] - d[j]) for j in range(n) if j != i] or [np.linalg.norm(d[i])]
        tol = 0.5 * min(gaps)
        delta = b[i] - a[i]
        out.append(bool(np.all(np.isfinite(delta)) and np.linalg.norm(delta - d[i]) < tol))
    return out
