"""Blur-, scale- and brightness-invariant features from the whole-signal Hu moments of a spot.

:func:`controller.imaging.blur_moments.blur_invariant_hu` gives phi_1..phi_7 of the per-unit-energy
central moments c_pq = mu_pq / mu_00 (Flusser & Suk 1998): phi_2..phi_7 are unchanged by a
circularly symmetric blur (a source disc, defocus), phi_1 grows by 2 sigma^2. Each scales with
the image (zoom s) as s^d_i (d = DEGREE_PX), so the signed roots

    rho_i = sign(phi_i) |phi_i|^(1/d_i)      (a length in px, proportional to s)

are all proportional to the same s. The features are the direction of (rho_2, ..., rho_7):

    b = (rho_2, ..., rho_7) / |(rho_2, ..., rho_7)|

invariant to a circular blur (each rho_i is), to zoom (the common factor s cancels), to
brightness (c_pq is per unit energy) and to rotation (Hu). phi_1 is left out: it is the only
blur-variant one, and any normaliser built from it (a size) would bring the blur back.
What is lost with it: the spot's elongation relative to its size (a round spot and a long bar
differ in rho_2 / rho_1, not in b alone) - why ``multi-blur-hu`` keeps the thresholded Hu
stack beside b.
"""

from __future__ import annotations

import numpy as np

from controller.imaging.blur_moments import signed_root

_TINY_PX = 1e-12  # a spot with every invariant zero (perfectly round and symmetric) gives b = 0


def blur_features(phi: np.ndarray) -> np.ndarray:
    """b (6,) from phi_1..phi_7 of :func:`~controller.imaging.blur_moments.blur_invariant_hu`
    (see the module docstring)."""
    rho = signed_root(phi)[1:]
    return rho / max(float(np.linalg.norm(rho)), _TINY_PX)
