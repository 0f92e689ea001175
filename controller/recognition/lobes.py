"""Hu moments of every lobe of a beam spot: all regions above a threshold, not only the largest.

:func:`controller.imaging.beam.analyze` keeps the most energetic 8-connected region above its
threshold: right for the centroid and the ellipse of one spot, but a mis-canted facet, facets
canted apart or a sagging structure throw *detached* lobes, and the region keeps one of them, so
a spot of three separate lobes looks like a plain round spot. The lobe row of ``multi-lobe-hu``
(:mod:`controller.recognition.features`) describes the union of all lobes instead:

1. background: the frame-wide σ-clipped plane of ``analyze`` (:func:`estimate_background`);
2. s = image − background; the threshold test runs on a Gaussian-smoothed copy (σ = 1 px, 5×5,
   as ``analyze``) so that a hot pixel neither sets the peak nor makes a lobe;
3. mask = smoothed > ``threshold`` × smoothed peak; its 8-connected regions are kept when they
   hold at least ``LOBE_SHARE`` of the smoothed energy above the threshold (a noise speck or a
   hot pixel does not; a facet's lobe does);
4. Hu's φ1…φ7 (Gonzalez & Woods Eqs. 11.3-17…26) of s inside the kept regions at **unit mean**
   over them, as ``analyze`` does for one region (η is then invariant to a zoom; see
   docs/recognition.md, "Pitfalls").

Pure: numpy image in (rows, cols; x = column, y = row), seven numbers out.
"""

from __future__ import annotations

import cv2
import numpy as np

from controller.errors import InputError
from controller.imaging.background import Background, estimate_background, subtract_background
from controller.imaging.beam import SMOOTH_PX, check_image
from controller.imaging.moments import central_moments, hu_from_eta, normalised_central_moments

LOBE_SHARE = 0.01  # a region holding less of the energy above the threshold is noise, not a lobe


def lobes_hu(image: np.ndarray, threshold: float, background: Background | None = None) -> np.ndarray:
    """Hu moments (7,) of all lobes of the beam above ``threshold`` × its smoothed peak (see the
    module docstring); ``background``: step 1's plane when estimated already. InputError when
    there is no beam."""
    img = check_image(image)
    bg = estimate_background(img) if background is None else background
    signal = subtract_background(img, bg).astype(np.float32)
    smooth = cv2.GaussianBlur(signal, (5, 5), SMOOTH_PX, borderType=cv2.BORDER_REPLICATE)
    peak = float(smooth.max())
    if not peak > 0.0:
        raise InputError("no beam: nothing above the background")
    above = smooth > threshold * peak
    n, labels = cv2.connectedComponents(above.view(np.uint8), connectivity=8)
    energy = np.bincount(labels.ravel(), weights=np.where(above, smooth, 0.0).ravel(), minlength=n)
    energy[0] = 0.0  # label 0 is everything below the threshold
    region = (energy >= LOBE_SHARE * energy.sum())[labels] & above
    rows = np.flatnonzero(region.any(axis=1))
    cols = np.flatnonzero(region.any(axis=0))
    box = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
    weights = np.where(region[box], signal[box].astype(np.float64), 0.0)
    cm = central_moments(weights)
    if not cm.m00 > 0.0:
        raise InputError("no beam: the lobes above the threshold have no energy")
    # Unit mean intensity over the lobes: eta scales as mean^-(p+q)/2 (moments.normalise_intensity).
    return hu_from_eta(normalised_central_moments(cm.scaled(np.count_nonzero(region) / cm.m00)))
