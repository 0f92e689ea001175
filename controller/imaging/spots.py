"""Several beam spots in one image, each in its own slot's window, and whose spot is whose by a
known step (``calibration.beams_per_target`` K > 1, docs/campaigns.md).

**Windows.** Slot i's window is the rectangle of pixels ``windows[i] = (r0, r1, c0, c1)``
(half-open) around its aim point, as large as a spot's reach plus the identity step
(:mod:`controller.calibration.beams.slots`, Eq. 1); the slot layout keeps the windows disjoint.

**Background and noise.** The image is smoothed by a Gaussian of σ = ``SMOOTH_PX`` pixels;
the background b is the median and the noise σ_b 1.4826 × the median absolute deviation of
the smoothed pixels *outside every window* (the lit target away from the spots).

**A spot in a window** when the window's peak smoothed excess over b is above ``SNR`` σ_b.
Its position is the energy centroid of the excess s = I − b over the window's pixels whose
smoothed excess is above ``FLOOR`` of that peak and above 3 σ_b (x = column, y = row).

**How far a window's spot moved** between two captures (:func:`window_shifts`): the shift
Δ that best registers window i of the first capture onto the second, the peak of their
zero-mean normalised cross-correlation over shifts up to ``max_shift_px`` (smoothed images
less their background, windows larger than ``MATCH_PX`` averaged down by an integer factor
first; a parabola through the peak and its neighbours gives the fraction of a pixel). A
whole-spot registration, not a difference of centroids: a spot larger than its window is
clipped at the window's edges in both captures, which pulls both thresholded centroids
towards the window's centre and shrank measured steps by up to a third in the simulated
plant; the clipped spot still registers by its full shift.

**Identity by a known step.** Between two captures every heliostat of the capture moved by
its own known step, whose displacement on the target d_i (m, target axes u, v) is predicted
from its model, all distinct. Heliostat i's spot is *confirmed* when its window holds a spot
in both captures and that spot moved with i's step:

    |Δ_i − d_i| < tol,   tol = ½ min_{j≠i} |d_i − d_j|                               (1)

(with one heliostat, tol = ½ |d_i|: its spot must move at all). Since the d_j are at least
2 tol apart, a Δ_i within tol of d_i is farther than tol from every other d_j: a spot that
moved with another heliostat's step — two heliostats whose spots were exchanged — is never
confirmed. Anything else (a window empty in either capture, a spot that did not move as
predicted) leaves i *unconfirmed*: it is measured again alone
(:mod:`controller.calibration.beams.group`). So is a confirmed spot that reaches its window's
border (:func:`spills`): isolating it would cut it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from controller.imaging.centroid import SPECK_SIGMAS, robust_level, significant

SMOOTH_PX = 2.0
SNR = 8.0
FLOOR = 0.05
MATCH_PX = 96  # a window is registered at most this many pixels across (Δ's resolution: 1/10 of its factor)
BAND = 0.1  # the border band :func:`spills` takes off, a fraction of the window's size
# A registration less correlated than this is no shift: the cell's content did not move as one
# — a spot that changed, or two spots that moved apart: another heliostat's beam in the cell,
# whose energy would be in this one's centroid. A spot stepped alone correlates ≥ 0.99 on the
# simulated plant; one with another's spot on it, 0.83 (tests/calibration/beams/test_beams_sim.py).
MIN_MATCH = 0.9


def _smooth(img: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(img, (0, 0), SMOOTH_PX)


def _outside(shape: tuple[int, int], windows) -> np.ndarray:
    out = np.ones(shape, bool)
    for r0, r1, c0, c1 in windows:
        out[r0:r1, c0:c1] = False
    return out


def _level(sm: np.ndarray, windows) -> tuple[float, float]:
    """(b, σ_b) of the smoothed image ``sm`` outside every window."""
    out = sm[_outside(sm.shape, windows)]
    if out.size == 0:
        out = sm.ravel()
    b, sigma = robust_level(out)
    return b, max(sigma, 1e-9)


class Excess(NamedTuple):
    """An image over its background (module docstring): ``img`` float32, ``sm`` its smoothed
    excess over b, the background ``b`` and the noise σ_b. The functions below take it in place
    of the image, so a round's captures are smoothed and levelled once."""

    img: np.ndarray
    sm: np.ndarray
    b: float
    noise: float


def excess(hdr, windows) -> Excess:
    """``hdr`` over its background outside every one of ``windows``; an Excess as it is."""
    if isinstance(hdr, Excess):
        return hdr
    img = np.asarray(hdr, np.float32)
    sm = _smooth(img)
    b, noise = _level(sm, windows)
    sm -= b
    return Excess(img, sm, b, noise)


def window_spots(hdr, windows) -> np.ndarray:
    """The spot of each of the n ``windows`` (r0, r1, c0, c1) of ``hdr`` (an image or its
    :class:`Excess`): its (x, y) px, NaN when the window holds none (module docstring): (n, 2)."""
    img, sm, b, noise = excess(hdr, windows)
    out = np.full((len(windows), 2), np.nan)
    for k, (r0, r1, c0, c1) in enumerate(windows):
        w, s = sm[r0:r1, c0:c1], img[r0:r1, c0:c1] - b
        if w.size == 0:
            continue
        peak = float(w.max())
        if peak <= SNR * noise:
            continue
        keep = _weighed(w, noise, FLOOR) > 0.0  # the centroid's mask, as a cell's measurement weighs it
        c = _centroid(np.where(keep, np.clip(s, 0.0, None), 0.0))
        if c is not None:
            out[k] = (c0 + c[0], r0 + c[1])
    return out


def spills(hdr, windows, facing, floor: float = 0.0) -> np.ndarray:
    """How far (px) the energy centroid in each window moves when the window loses a border band
    of ``BAND`` of its size on the sides ``facing`` another slot (n × 4 bools: first rows, last
    rows, first columns, last columns): ~0 for a spot inside its window, large for one that
    reaches past a side towards another spot, where its part beyond is flattened away when it
    is isolated (:func:`isolate`) and another spot's tail may lie. The excess over the
    background above 3 σ_b and above ``floor`` times the window's peak is weighed (module
    docstring): with ``floor`` the measurement's centroid threshold
    (:func:`controller.imaging.centroid.energy_centroid`), a tail too faint to weigh in the
    centroid does not count. NaN for a window without any. ``hdr``: an image or its :class:`Excess`."""
    _, sm, _, noise = excess(hdr, windows)
    out = np.full(len(windows), np.nan)
    for k, ((r0, r1, c0, c1), sides) in enumerate(zip(windows, facing, strict=True)):
        e = _weighed(sm[r0:r1, c0:c1], noise, floor)
        h, w = e.shape
        br, bc = max(1, round(BAND * h)), max(1, round(BAND * w))
        top, bottom, left, right = (bool(x) for x in sides)
        rows = slice(br if top else 0, h - br if bottom else h)
        cols = slice(bc if left else 0, w - bc if right else w)
        inner = np.zeros_like(e)
        inner[rows, cols] = e[rows, cols]
        cs = [_centroid(x) for x in (e, inner)]
        if all(c is not None for c in cs):
            out[k] = float(np.hypot(*(cs[0] - cs[1])))
    return out


def cell_centroids(hdr, cells, windows, floor: float = 0.0) -> np.ndarray:
    """The energy centroid (x, y) px of each of the n ``cells`` (r0, r1, c0, c1) of ``hdr`` (an
    image or its :class:`Excess`, the background taken outside every one of ``windows``): the
    excess above 3 σ_b and above ``floor`` times the cell's peak, as a measurement of that cell
    weighs it (:func:`controller.imaging.centroid.energy_centroid`); NaN for a cell without any."""
    _, sm, _, noise = excess(hdr, windows)
    out = np.full((len(cells), 2), np.nan)
    for k, (r0, r1, c0, c1) in enumerate(cells):
        c = _centroid(_weighed(sm[r0:r1, c0:c1], noise, floor))
        if c is not None:
            out[k] = c + (c0, r0)
    return out


def _weighed(region: np.ndarray, noise: float, floor: float) -> np.ndarray:
    """``region`` of the smoothed excess where it is above 3 σ_b and ``floor`` times its peak
    (a measurement's centroid threshold) in parts that rise :data:`SPECK_SIGMAS` σ_b above the
    background (:func:`controller.imaging.centroid.significant`: not noise specks), 0 elsewhere."""
    if region.size == 0:
        return region
    mask = region > max(3.0 * noise, floor * float(region.max(initial=0.0)))
    return np.where(significant(region, mask, SPECK_SIGMAS * noise), region, 0.0)


def _centroid(e: np.ndarray) -> np.ndarray | None:
    total = float(e.sum())
    if total <= 0:
        return None
    rows, cols = np.indices(e.shape)
    return np.array([(e * cols).sum(), (e * rows).sum()]) / total


def window_shifts(first, second, regions, max_shift_px: int, windows) -> np.ndarray:
    """How far the content of each of the n ``regions`` (r0, r1, c0, c1) moved from image
    ``first`` to image ``second`` (images or their :class:`Excess`; module docstring, the
    background b taken outside every one of ``windows``): (n, 2) px (x, y), NaN where no shift
    up to ``max_shift_px`` registers it (correlation below ``MIN_MATCH`` or its peak at the limit)."""
    ims = [excess(hdr, windows).sm for hdr in (first, second)]
    out = np.full((len(regions), 2), np.nan)
    for k, (r0, r1, c0, c1) in enumerate(regions):
        f = max(1, -(-max(r1 - r0, c1 - c0) // MATCH_PX))
        reach = -(-max(1, int(max_shift_px)) // f)  # shifts searched, in averaged pixels
        pad = reach * f
        tpl = _shrink(ims[0][r0:r1, c0:c1], f)
        big = cv2.copyMakeBorder(ims[1], pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0.0)
        search = _shrink(big[r0:r0 + (r1 - r0) + 2 * pad, c0:c0 + (c1 - c0) + 2 * pad], f)
        if tpl.size == 0 or float(tpl.std()) == 0.0:
            continue
        res = cv2.matchTemplate(search, tpl, cv2.TM_CCOEFF_NORMED)
        _, peak, _, (px, py) = cv2.minMaxLoc(res)
        if peak < MIN_MATCH or not (0 < px < res.shape[1] - 1 and 0 < py < res.shape[0] - 1):
            continue
        dx, dy = _vertex(res[py, px - 1:px + 2]), _vertex(res[py - 1:py + 2, px])
        out[k] = ((px + dx - reach) * f, (py + dy - reach) * f)
    return out


def _shrink(img: np.ndarray, f: int) -> np.ndarray:
    """``img`` averaged over f × f blocks (the last partial blocks dropped)."""
    if f == 1:
        return np.ascontiguousarray(img, np.float32)
    h, w = (img.shape[0] // f) * f, (img.shape[1] // f) * f
    return np.ascontiguousarray(img[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3)), np.float32)


def _vertex(three: np.ndarray) -> float:
    """The vertex of the parabola through three equally spaced values, from the middle one."""
    a, b, c = (float(v) for v in three)
    den = a - 2.0 * b + c
    return 0.0 if den >= 0 else 0.5 * (a - c) / den


def isolate(hdr: np.ndarray, windows, cell, level: float | None = None) -> np.ndarray:
    """``hdr`` with everything outside the rectangle ``cell`` (r0, r1, c0, c1) — a spot's own
    window, or the larger cell its slot was given (slots.py, Eq. 2) — replaced by the
    background level b outside every one of ``windows`` (``level``: b when already known): the
    other spots and the faint tails they spread beyond their windows, which an energy centroid
    without a threshold would average in."""
    img = np.asarray(hdr, float)
    b = excess(hdr, windows).b if level is None else level
    out = np.full_like(img, b)
    r0, r1, c0, c1 = cell
    out[r0:r1, c0:c1] = img[r0:r1, c0:c1]
    return out


@dataclass(frozen=True)
class Isolated:
    """One heliostat's spot in a shared capture (``beams_per_target`` K > 1): called with the
    capture's HDR image, that image with everything outside ``cell`` flattened to ``level``
    (:func:`isolate`; the spot's shape for the library); :meth:`measured` puts an observation's
    centroid where the cell's weighed energy lies (``centroid_px`` (x, y) and ``centroid_enu``
    m, :func:`cell_centroids`: the excess over the background of the view's spot-free pixels).
    The analysis of the flattened image fits its background to the flat fill, which is not the
    cell's own background (the spot-free pixels between windows hold the spots' faint tails):
    the offset weighs a small spot's quantised wings unevenly, and put the centroids of the
    simulated plant's four-beam rounds up to 1 m from the true hit (p99 0.19 m, against
    0.05 m for the cell's weighed energy; docs/results.md)."""

    windows: list
    cell: tuple[int, int, int, int]
    level: float | None
    centroid_px: tuple[float, float]
    centroid_enu: tuple[float, float, float]

    def __call__(self, hdr) -> np.ndarray:
        return isolate(hdr, self.windows, self.cell, self.level)

    def measured(self, obs):
        """``obs`` (an observation dataclass with ``centroid_px`` and ``centroid_enu``) with this
        spot's centroid; unchanged when the cell held no weighed energy."""
        if not np.isfinite(self.centroid_px).all():
            return obs
        return replace(obs, centroid_px=tuple(self.centroid_px), centroid_enu=tuple(self.centroid_enu))


def moved_across(first_m: np.ndarray, second_m: np.ndarray, steps_m: np.ndarray) -> np.ndarray:
    """How far (m) each of n points moved across its predicted displacement: ``first_m`` and
    ``second_m`` (n, 2) m where it was in the two captures, ``steps_m`` (n, 2) m the displacement
    (|d̂ × Δ|); NaN where either is missing."""
    d = np.asarray(second_m, float).reshape(-1, 2) - np.asarray(first_m, float).reshape(-1, 2)
    s = np.asarray(steps_m, float).reshape(-1, 2)
    u = s / np.maximum(np.linalg.norm(s, axis=1, keepdims=True), 1e-12)
    return np.abs(u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0])


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
