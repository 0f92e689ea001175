"""The beam's energy centroid: every pixel of the (background-free) image above a fraction of
the peak weighs in, so a detached or dim lobe of the beam pulls the centroid too.

Conventions: image x = column, y = row, pixel centres at integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class EnergyCentroid:
    """``x``, ``y``: energy centroid, px; ``total``: summed signal above the threshold and
    ``peak``: the smoothed image's maximum, in image units; ``clipped``: edges of the view the
    above-threshold region touches."""

    x: float
    y: float
    total: float
    peak: float
    clipped: tuple[str, ...]


def energy_centroid(signal: np.ndarray, rel_threshold: float, smooth_sigma_px: float = 1.0) -> EnergyCentroid:
    """Energy centroid of ``signal`` (2-D, background already subtracted).

    Pixels where the Gaussian-smoothed image (σ = ``smooth_sigma_px``) exceeds
    ``rel_threshold`` × its maximum form the mask M; with s the unsmoothed signal,

        x̄ = Σ_M s·x / Σ_M s,   ȳ = Σ_M s·y / Σ_M s.

    The smoothing only decides the mask (single noisy pixels do not); the weights are the
    measured signal. A mask touching an edge means the beam may be cut off by the view, which
    biases the centroid inwards: the edges are reported, the caller decides. NaN coordinates
    when nothing is above the threshold.
    """
    s = np.asarray(signal, dtype=np.float32)
    if s.ndim != 2 or s.size == 0:
        raise ValueError(f"signal must be a non-empty 2-D image, got shape {s.shape}")
    smooth = cv2.GaussianBlur(s, (0, 0), smooth_sigma_px)
    peak = float(smooth.max())
    above = smooth > rel_threshold * peak
    clipped = tuple(name for name, e in (("top", above[0]), ("bottom", above[-1]), ("left", above[:, 0]),
                                         ("right", above[:, -1])) if e.any())
    w = np.where(above, s, 0.0).astype(np.float64)
    total = float(w.sum())
    if not total > 0:
        return EnergyCentroid(float("nan"), float("nan"), total, peak, clipped)
    rows, cols = s.shape
    x = float(w.sum(axis=0) @ np.arange(cols)) / total
    y = float(w.sum(axis=1) @ np.arange(rows)) / total
    return EnergyCentroid(x, y, total, peak, clipped)
