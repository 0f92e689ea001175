"""Image moments and Hu's seven invariants of a grey-level image.

Conventions: the image is a 2-D array (rows, cols); x = column, y = row, with (0, 0) the centre
of the top-left pixel. Everything is computed in float64, whatever the input dtype.

Pitfalls (see docs/recognition.md):

* Grey-level Hu moments are *not* brightness invariant: scaling the intensity by k scales
  phi_1..phi_7 by k^-[1, 2, 3, 3, 6, 4, 6]. Normalise the intensity before comparing spots
  (:func:`normalise_intensity`).
* A background pedestal, even 0.1 % of the peak, dominates mu_00 and so phi_1 and phi_5.
  Subtract the background and segment the spot first (:mod:`controller.imaging.beam`).
* Mirroring the image flips the sign of phi_7 (it is a skew invariant).
* For near-symmetric spots phi_5 and phi_7 are close to zero and mostly noise; on a log scale
  they swamp the distance.
* float32 sums lose digits on megapixel images, so moments are always accumulated in float64.

References
----------
.. [1] M.-K. Hu, "Visual pattern recognition by moment invariants", IRE Trans. Inf. Theory
   8(2), 179-187, 1962.
.. [2] R. C. Gonzalez, R. E. Woods, *Digital Image Processing*, 3rd ed., Sec. 11.3.4,
   Eqs. (11.3-17)-(11.3-25), Pearson, 2008.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CentralMoments:
    """Raw mass, centroid and central moments mu_pq (p + q <= 3) of an image, float64.

    ``m00`` is the total intensity; ``cx``, ``cy`` the centroid in pixels (x = column);
    ``mu`` maps "pq" -> mu_pq in intensity * pixel^(p+q).
    """

    m00: float
    cx: float
    cy: float
    mu: dict[str, float]

    def scaled(self, k: float) -> CentralMoments:
        """Moments of the image multiplied by ``k`` (every moment is linear in intensity)."""
        return CentralMoments(m00=self.m00 * k, cx=self.cx, cy=self.cy,
                              mu={p: v * k for p, v in self.mu.items()})


def central_moments(image: np.ndarray) -> CentralMoments:
    """Central moments up to third order, Gonzalez & Woods Eq. (11.3-17)/(11.3-18).

    mu_pq = sum_x sum_y (x - xbar)^p (y - ybar)^q f(x, y), with xbar = m10/m00, ybar = m01/m00.
    Computed from the row and column marginals (two passes over the image), which is exact
    for the mixed terms too because they are built from per-row weighted sums.

    Parameters
    ----------
    image : ndarray (rows, cols), any real dtype; must have a non-zero sum.

    Returns
    -------
    CentralMoments
    """
    f = np.asarray(image, dtype=np.float64)
    if f.ndim != 2:
        raise ValueError(f"expected a 2-D image, got shape {f.shape}")
    m00 = float(f.sum())
    if m00 == 0.0 or not np.isfinite(m00):
        raise ValueError("image has zero (or non-finite) total intensity; moments are undefined")
    rows, cols = f.shape
    x = np.arange(cols, dtype=np.float64)
    y = np.arange(rows, dtype=np.float64)
    col_sum = f.sum(axis=0)  # marginal over rows, indexed by x
    row_sum = f.sum(axis=1)  # marginal over columns, indexed by y
    cx = float(col_sum @ x) / m00
    cy = float(row_sum @ y) / m00
    dx = x - cx
    dy = y - cy
    # Per-row first and second x-moments give the mixed terms without a full (rows, cols) grid.
    # einsum, not "@": a threaded BLAS matrix-vector product is ~20x slower on a busy 2-core host.
    fx1 = np.einsum("ij,j->i", f, dx)
    fx2 = np.einsum("ij,j->i", f, dx * dx)
    mu = {
        "20": float(col_sum @ (dx * dx)),
        "02": float(row_sum @ (dy * dy)),
        "11": float(fx1 @ dy),
        "30": float(col_sum @ (dx * dx * dx)),
        "03": float(row_sum @ (dy * dy * dy)),
        "21": float(fx2 @ dy),
        "12": float(fx1 @ (dy * dy)),
    }
    return CentralMoments(m00=m00, cx=cx, cy=cy, mu=mu)


def normalised_central_moments(cm: CentralMoments) -> dict[str, float]:
    """eta_pq = mu_pq / mu_00^((p+q)/2 + 1), Gonzalez & Woods Eq. (11.3-19)."""
    return {k: v / cm.m00 ** ((int(k[0]) + int(k[1])) / 2.0 + 1.0) for k, v in cm.mu.items()}


def hu_from_eta(eta: dict[str, float]) -> np.ndarray:
    """Hu's seven invariants phi_1..phi_7 from normalised central moments.

    Hu (1962) Eqs. (94); Gonzalez & Woods Eqs. (11.3-20)-(11.3-26). phi_7 is the skew
    invariant and starts with (3 eta_21 - eta_03), as in Hu's paper.
    """
    n20, n02, n11 = eta["20"], eta["02"], eta["11"]
    n30, n03, n21, n12 = eta["30"], eta["03"], eta["21"], eta["12"]
    a = n30 + n12
    b = n21 + n03
    phi = np.empty(7, dtype=np.float64)
    phi[0] = n20 + n02
    phi[1] = (n20 - n02) ** 2 + 4.0 * n11**2
    phi[2] = (n30 - 3.0 * n12) ** 2 + (3.0 * n21 - n03) ** 2
    phi[3] = a**2 + b**2
    phi[4] = (n30 - 3.0 * n12) * a * (a**2 - 3.0 * b**2) + (3.0 * n21 - n03) * b * (3.0 * a**2 - b**2)
    phi[5] = (n20 - n02) * (a**2 - b**2) + 4.0 * n11 * a * b
    phi[6] = (3.0 * n21 - n03) * a * (a**2 - 3.0 * b**2) - (n30 - 3.0 * n12) * b * (3.0 * a**2 - b**2)
    return phi


def hu_moments(image: np.ndarray) -> np.ndarray:
    """Hu's seven moment invariants of a grey-level image, float64, shape (7,).

    No intensity normalisation is applied, so the result equals
    ``cv2.HuMoments(cv2.moments(image.astype(float64)))`` (to ~1e-12 relative on phi_1-phi_4).
    For comparing spots of different brightness, pass ``normalise_intensity(image)``.

    Parameters
    ----------
    image : ndarray (rows, cols), any real dtype, non-zero sum. x = column, y = row.

    Returns
    -------
    ndarray (7,) : phi_1..phi_7 (dimensionless for a unit-mean image).

    References
    ----------
    Hu (1962) Eqs. (94); Gonzalez & Woods (2008) Eqs. (11.3-17)-(11.3-26).
    """
    return hu_from_eta(normalised_central_moments(central_moments(image)))


def normalise_intensity(image: np.ndarray) -> np.ndarray:
    """Scale a segmented spot to unit mean over its non-zero pixels, float64.

    Why unit *mean* and not unit sum: for a grey image eta_pq is invariant to a geometric
    zoom s (mu_pq ~ s^(p+q+2), mu_00 ~ s^2) but scales with brightness k as k^-(p+q)/2.
    Dividing by the mean over the spot's support removes k and keeps the zoom invariance;
    dividing by the sum would instead introduce a factor s^(p+q) from the support's area.
    """
    f = np.asarray(image, dtype=np.float64)
    support = f != 0
    n = int(np.count_nonzero(support))
    if n == 0:
        raise ValueError("image is all zero; cannot normalise intensity")
    return f * (n / float(f[support].sum()))
