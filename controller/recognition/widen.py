"""Widened copies of a beam image: the same spot as a larger source or a softer focus shows it.

A beam spot is the error's pattern convolved with the image of the source (the sun's or a lamp's
disc through the mirror, plus the camera's blur). A larger source, a shorter slant or a softer
focus widens that kernel; the error's pattern stays as it is. To the Hu moments, which ignore
zoom, a spot of size s showing an error of magnitude m therefore looks like the case at the
*relative* magnitude m / s, and a view with a smaller spot than the library's lies beyond its
largest magnitude. Convolving such a view with a Gaussian of σ = ``fraction`` × its d90 (the
diameter holding 90 % of its energy above 0.1 of the peak) moves it back towards the library's
spot size (:meth:`controller.recognition.library.Library.match_image` tries this only for a view
that is otherwise unknown); the library's own blurred views (``augmented_views``) use the same
kernel to learn how a larger spot moves the features.

Pure: numpy image in (rows, cols; x = column, y = row), numpy image out.
"""

from __future__ import annotations

import cv2
import numpy as np

from controller.imaging.beam import analyze

# Kernels (σ / d90) tried, in order, on a view that no case claims: a spot up to ~1.5 x smaller
# than the library's comes back within reach (σ = 0.2 d90 roughly doubles a Gaussian spot's σ).
WIDEN = (0.1, 0.2)
# A widened view is a guess at the spot size: it is taken for a case only well inside that case's
# unknown threshold. Leaving each of the six cases out of the library in turn (two independent
# renderers, docs/recognition.md), this keeps 26 of 144 views of the missing case rejected
# where accepting up to the threshold kept 18-22, and costs the six-case sets nothing.
WIDEN_ACCEPT = 0.5
D90_THRESHOLD = 0.1  # the spot's extent at 0.1 of its peak: the halo, as the lowest descriptor row
MIN_SIGMA_PX = 0.3  # below this a Gaussian kernel of OpenCV is the identity


def spot_d90(image: np.ndarray) -> float:
    """The beam's d90 (px) at 0.1 of its peak, background estimated
    (:func:`controller.imaging.beam.analyze`)."""
    return analyze(image, threshold=D90_THRESHOLD, background="auto", centroid="segment",
                   presence=False).d90_px


def widened(image: np.ndarray, fraction: float, d90_px: float) -> np.ndarray:
    """The image convolved with a Gaussian of σ = ``fraction`` × ``d90_px`` (px, at least
    0.3 px), edges replicated so the background plane stays a plane."""
    img = np.asarray(image, dtype=np.float32)
    return cv2.GaussianBlur(img, (0, 0), sigmaX=max(fraction * d90_px, MIN_SIGMA_PX),
                            borderType=cv2.BORDER_REPLICATE)
