"""Moment invariants to centrosymmetric blur: Hu's phi_2..phi_7 of the whole spot signal.

A larger source disc or a softer focus convolves the beam image f with a point-spread function
h. Central moments of a convolution (Flusser & Suk 1998, Eq. 5)::

    mu_pq(f * h) = sum_{k=0..p} sum_{j=0..q} C(p, k) C(q, j) mu_kj(f) mu_{p-k, q-j}(h)

With h centrosymmetric (h(x, y) = h(-x, -y): its odd-order moments vanish) and of unit mass
(mu_00(h) = 1, energy is conserved):

* mu_00(f * h) = mu_00(f);
* mu_pq(f * h) = mu_pq(f) for p + q = 3 (every cross term holds an odd moment of h or a first
  central moment of f, both zero);
* with h circularly symmetric (mu_20(h) = mu_02(h) = sigma^2, mu_11(h) = 0):
  mu_20 += sigma^2 mu_00, mu_02 += sigma^2 mu_00, mu_11 unchanged.

So with eta_pq = mu_pq / mu_00^(1 + (p+q)/2) (Gonzalez & Woods Eq. 11.3-19; mu_00 is unchanged,
so the normalisation keeps the invariance), Hu's phi_3..phi_7 (third order, and phi_6's
eta_20 - eta_02 and eta_11) and phi_2 = (eta_20 - eta_02)^2 + 4 eta_11^2 are invariant to a
circularly symmetric blur; phi_1 = eta_20 + eta_02 is not (it grows by 2 sigma^2 / mu_00).
An asymmetric PSF (a one-sided smear) changes the third-order moments and so the features.

This holds only for moments taken over the *whole* spot signal: a hard threshold clips the
blurred tails and breaks it. :func:`blur_invariant_hu` therefore takes the background-subtracted
signal in a generous window around the spot (noise included, no threshold inside the window).

Normalisation: the grey-level eta_pq scales with the intensity as k^-(p+q)/2, and no intensity
normaliser of the spot (peak, mean over a region) is itself blur invariant. The only one that is
is mu_00, so the moments are taken per unit energy, c_pq = mu_pq / mu_00 (px^(p+q)): brightness
and blur invariant, but they grow with the image scale s as s^(p+q); the feature kind divides
that out (:mod:`controller.recognition.blur_features`).

Conventions: image (rows, cols), x = column, y = row, (0, 0) the centre of the top-left pixel;
float64 sums.

References
----------
.. [1] J. Flusser, T. Suk, "Degraded image analysis: an invariant approach", IEEE TPAMI 20(6),
   590-603, 1998.
.. [2] J. Flusser, T. Suk, B. Zitova, *2D and 3D Image Analysis by Moments*, Wiley 2016, ch. 6.
"""

from __future__ import annotations

import numpy as np

from controller.errors import InputError
from controller.imaging.beam import analyze
from controller.imaging.moments import central_moments, hu_from_eta

WINDOW_THRESHOLD = 0.05  # the spot's extent: 5 % of its smoothed peak
WINDOW_MARGIN = 1.0  # the window reaches this fraction of the spot's extent beyond it on every side
# Degree of phi_i in the moments (phi_1: 1, phi_2..phi_4: 2, phi_5: 4, phi_6: 3, phi_7: 4) times
# their order: sign(phi)|phi|^(1/DEGREE_PX) is a length in pixels.
DEGREE_PX = np.array([2.0, 4.0, 6.0, 6.0, 12.0, 8.0, 12.0])


def energy_moments(image: np.ndarray, threshold: float = WINDOW_THRESHOLD,
                   margin: float = WINDOW_MARGIN) -> dict[str, float]:
    """c_pq = mu_pq / mu_00 (px^(p+q), 2 <= p + q <= 3) of the whole background-subtracted spot.

    The spot's extent is where its smoothed signal exceeds ``threshold`` x its peak
    (:func:`controller.imaging.beam.analyze`, background ``auto``: sigma-clipped plane); the
    window is that box grown by ``margin`` x its size on every side (clipped to the frame), and
    every pixel in it counts with its background-subtracted value, noise and negative values
    included, so the blurred tails are not clipped (the condition of the blur invariance).
    InputError when there is no beam or no positive energy in the window.
    """
    res = analyze(image, threshold=threshold, background="auto", centroid="segment", presence=False)
    b0, b1, a0, a1 = res.bbox
    cx, cy = (int(round(v)) for v in res.centroid_px)
    # Symmetric about the centroid, so that what is left of the background (a constant, or the
    # error of its plane) adds nothing to the odd (third-order) moments.
    ext_r, ext_c = max(cy - b0, b1 - 1 - cy, 1), max(cx - a0, a1 - 1 - cx, 1)
    hr, hc = int(np.ceil((1.0 + margin) * ext_r)), int(np.ceil((1.0 + margin) * ext_c))
    rows, cols = np.shape(image)
    r0, r1, c0, c1 = max(cy - hr, 0), min(cy + hr + 1, rows), max(cx - hc, 0), min(cx + hc + 1, cols)
    win = np.asarray(image, dtype=np.float64)[r0:r1, c0:c1]
    return _per_unit_energy(win - _ring_plane(win, res, (cy - r0, cx - c0), (ext_r, ext_c), margin, (r0, c0)))


def _ring_plane(win: np.ndarray, res, centre: tuple[int, int], extent: tuple[int, int], margin: float,
                origin: tuple[int, int]) -> np.ndarray:
    """Background over the window: the plane a + b x + c y fitted by least squares to its outer
    ring (beyond the spot's extent grown by half the margin), so that the plane is right where the
    third-order moments weigh most (the frame-wide plane of ``analyze`` is the fallback when the
    ring is too small, e.g. a window clipped by the frame)."""
    y, x = np.mgrid[0:win.shape[0], 0:win.shape[1]].astype(np.float64)
    inner = 1.0 + 0.5 * margin
    ring = ((np.abs(y - centre[0]) > inner * extent[0]) | (np.abs(x - centre[1]) > inner * extent[1]))
    if ring.sum() < 0.1 * ring.size:
        return res.background.evaluate(win.shape, np.float64, origin=origin)
    a = np.column_stack([np.ones(int(ring.sum())), x[ring], y[ring]])
    coef, *_ = np.linalg.lstsq(a, win[ring], rcond=None)
    return coef[0] + coef[1] * x + coef[2] * y


def _per_unit_energy(signal: np.ndarray) -> dict[str, float]:
    """c_pq = mu_pq / mu_00 of a background-subtracted window."""
    if not signal.sum() > 0:
        raise InputError("no beam: no energy above the background in the spot's window")
    cm = central_moments(signal)
    return {k: v / cm.m00 for k, v in cm.mu.items()}


def blur_invariant_hu(image: np.ndarray, threshold: float = WINDOW_THRESHOLD,
                      margin: float = WINDOW_MARGIN) -> np.ndarray:
    """Hu's phi_1..phi_7 (7,) of the per-unit-energy moments c_pq of :func:`energy_moments`.

    phi_2..phi_7 are invariant to a circularly symmetric blur (phi_3, phi_4, phi_5, phi_7 to any
    centrosymmetric one); phi_1 grows by 2 sigma^2 (sigma^2 = the PSF's second moment per axis).
    Units px^DEGREE_PX: they scale with the image as s^DEGREE_PX, brightness does not matter.
    """
    return hu_from_eta(energy_moments(image, threshold, margin))


def signed_root(phi: np.ndarray) -> np.ndarray:
    """sign(phi_i) |phi_i|^(1/DEGREE_PX_i): each invariant as a length in px, linear in the scale."""
    p = np.asarray(phi, dtype=np.float64)
    return np.sign(p) * np.abs(p) ** (1.0 / DEGREE_PX)
