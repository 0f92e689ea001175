"""The beam's energy centroid: every pixel of the (background-free) image above a fraction of
the peak weighs in, so a detached or dim lobe of the beam pulls the centroid too — but not a
speck of noise that happens to reach that fraction of a dim spot's peak (:func:`significant`).

Conventions: image x = column, y = row, pixel centres at integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from controller.imaging.background import median


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


def energy_centroid(signal: np.ndarray, rel_threshold: float, smooth_sigma_px: float = 1.0,
                    min_sigmas: float = 0.0) -> EnergyCentroid:
    """Energy centroid of ``signal`` (2-D, background already subtracted).

    Pixels where the Gaussian-smoothed image (σ = ``smooth_sigma_px``) exceeds
    ``rel_threshold`` × its maximum form the mask M; with s the unsmoothed signal,

        x̄ = Σ_M s·x / Σ_M s,   ȳ = Σ_M s·y / Σ_M s.

    The smoothing only decides the mask (single noisy pixels do not); the weights are the
    measured signal. ``min_sigmas`` > 0: only the parts of M that rise ``min_sigmas`` σ above
    the level of the pixels outside it count (:func:`significant`). A mask touching an edge
    means the beam may be cut off by the view, which biases the centroid inwards: the edges
    are reported, the caller decides. NaN coordinates when nothing is above the threshold.
    """
    s = np.asarray(signal, dtype=np.float32)
    if s.ndim != 2 or s.size == 0:
        raise ValueError(f"signal must be a non-empty 2-D image, got shape {s.shape}")
    smooth = cv2.GaussianBlur(s, (0, 0), smooth_sigma_px)
    peak = float(smooth.max())
    above = smooth > rel_threshold * peak
    if min_sigmas > 0 and above.any() and not above.all():
        level, sigma = robust_level(smooth[~above][::RATE])
        above = significant(smooth, above, level + min_sigmas * sigma)
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


RATE = 4  # every RATE-th pixel outside the mask gives its level and σ: a megapixel view costs no more
# How far (σ of the smoothed background) a part of a centroid's mask must rise above the
# background's level to weigh in: the cheap cameras' noise specks reach 6 σ (significant).
SPECK_SIGMAS = 8.0


def robust_level(values: np.ndarray) -> tuple[float, float]:
    """(level, σ) of ``values`` robust to the few that are not background: the median and
    1.4826 × the median absolute deviation (σ of a normal distribution)."""
    level = median(values)
    return level, 1.4826 * median(np.abs(values - level))


def significant(smooth: np.ndarray, mask: np.ndarray, floor: float) -> np.ndarray:
    """``mask`` without its 8-connected parts whose highest value of ``smooth`` is not above
    ``floor`` (the part holding the peak stays: whether that is a beam is the caller's call): a
    speck of noise that reaches a dim spot's threshold does not rise far above the background
    anywhere, a lobe of the beam does. (The simulated plant's 8-bit cheap cameras: a
    spot of peak 110 σ of the smoothed background, its threshold 5 % of that, 3.6 σ above the
    background's level; a dozen specks of up to 6 σ pulled its centroid 3.7 m towards the
    view's centre; issue 42.)"""
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n <= 1:
        return mask
    # A part rises above the floor where any of its pixels does: marking the labels of those
    # pixels needs no per-part maximum (ndimage.maximum sorts the whole image by label).
    keep = np.zeros(n + 1, bool)
    keep[labels[mask & (smooth > floor)]] = True
    peak = smooth[mask].max()
    keep[labels[mask & (smooth == peak)].min()] = True  # the first part at the peak, as argmax
    return keep[labels]  # label 0, outside the mask, is never kept
