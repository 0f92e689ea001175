"""Is there a beam on the target at all? The beam-presence decision, before any centroid.

Statistic (docs/imaging.md, "Beam presence"): the spot's smoothed excess over the background,
in units of the background's own spatial variation on this frame,

    z = (g_max − median_B(g)) / (1.4826 · MAD_B(g)),      g = G_σ * (I − b)                 (P1)

with b the sigma-clipped plane of :func:`controller.imaging.background.estimate_background`,
G_σ a Gaussian of σ = ``SIGMA_PX`` pixels of the analysis level (the image reduced by
``cv2.pyrDown`` until its longer side is at most ``LEVEL_SIDE`` px; σ is at most 1/16 of the
level's shorter side, so that a tiny image is not smoothed flat), g_max the maximum of g on
the target, and B the target's pixels outside the candidate spot's footprint (the connected
region of g above half-way from the median to g_max that holds g_max). MAD_B(g) is what a
target without a beam shows at the spot's scale: its texture, shading, lit patches and noise
after the same smoothing. A beam is present when z ≥ ``THRESHOLD``.

Why 5.5: for a background of white Gaussian noise, g is a smooth Gaussian field, and the chance
that its maximum over an area of A level pixels exceeds u of its standard deviations is about
the expected Euler characteristic of the excursion set (Worsley et al. 1996, 2-D):

    P(max z ≥ u) ≈ A / (2 σ²) · (2π)^(-3/2) · u · exp(−u²/2)                                  (P2)

For the largest level (320 × 320) and σ = 4 this is 3e-4 at u = 5.5 (300 noise frames of
256 × 256: maximum 5.04). Only the pixels at least 2 σ inside the view count (nearer the edge the
smoothing averages fewer independent pixels). Real empty Jülich targets stay far below it
(their spatial variation is smooth shading, not noise: z ≤ 3.5 on the 40 tuning photos) and the
faintest real beam photo reaches 8.9. The threshold comes from (P2), not from either set.

Conventions: image x = column, y = row, pixel centres at integer coordinates, full-resolution
pixels in every result.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from controller.imaging.background import Background, estimate_background, median

THRESHOLD = 5.5  # z of (P1) at and above which a beam is present
SIGMA_PX = 4.0  # σ of G in (P1), pixels of the analysis level
LEVEL_SIDE = 320  # the analysis level's longer side is at most this (px)
EXTENT = 0.1  # a candidate's extent: above this fraction of its peak excess
MIN_LEFT = 0.25  # of the target, outside a candidate's extent, to measure the background on
STATISTIC = "spatial_snr"  # the name of (P1) in JSON


@dataclass(frozen=True)
class Presence:
    """The decision and what it saw. ``statistic`` is z of (P1), ``threshold`` the bound it was
    compared with; ``peak_xy`` the maximum of g (full-resolution px); ``level`` the pyramid
    factor 2^k; ``level_image`` the image at that level, ``smoothed`` g, ``footprint`` its
    candidate spot (bool) and ``target`` the pixels considered (bool), all at that level;
    ``background`` the plane at full resolution; ``spread`` 1.4826 · MAD_B(g) and ``floor``
    median_B(g) (image units)."""

    beam: bool
    statistic: float
    threshold: float
    peak_xy: tuple[float, float]
    level: int
    level_image: np.ndarray
    smoothed: np.ndarray
    footprint: np.ndarray
    target: np.ndarray
    background: Background
    spread: float
    floor: float

    def as_dict(self) -> dict:
        """JSON keys ``beam``, ``statistic`` (value of (P1)), ``statistic_name``, ``threshold``."""
        z = self.statistic
        return {"beam": self.beam, "statistic": z if np.isfinite(z) else 1e308,
                "statistic_name": STATISTIC, "threshold": self.threshold}

    def reason(self) -> str:
        """One line saying why there is no beam (or that there is one)."""
        rel = "≥" if self.beam else "<"
        return (f"spot excess {self.statistic:.2f} {rel} {self.threshold:g} x the background's spatial "
                f"variation ({self.spread:.3g}) at ({self.peak_xy[0]:.0f}, {self.peak_xy[1]:.0f}) px")


def pyramid(image: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None, int]:
    """(level image float32, level mask, factor 2^k): ``cv2.pyrDown`` until the longer side is
    at most ``LEVEL_SIDE`` px; a level pixel (x, y) is full-resolution (2^k x, 2^k y)."""
    small = np.asarray(image, dtype=np.float32)
    m = None if mask is None else np.asarray(mask, bool)
    scale = 1
    while max(small.shape) > LEVEL_SIDE:
        small = cv2.pyrDown(small)
        scale *= 2
        if m is not None:
            m = m[::2, ::2][:small.shape[0], :small.shape[1]]
    return small, m, scale


def _footprint(g: np.ndarray, at: tuple[int, int], level: float) -> np.ndarray:
    """The 8-connected region of ``g > level`` holding pixel ``at`` (row, col)."""
    above = (g > level).view(np.uint8)
    _, labels = cv2.connectedComponents(above, connectivity=8)
    return labels == labels[at]


def _background_sample(g: np.ndarray, target: np.ndarray, at: tuple[int, int], base: float, peak: float,
                       core: np.ndarray) -> np.ndarray:
    """The values of g (every other row and column) that stand for the background: outside the
    candidate's extent (its connected region above ``EXTENT`` of the way from the median to the
    peak) while that leaves at least ``MIN_LEFT`` of the target, else outside its half-peak
    ``core``; a spot's tails must not count as the background's variation."""
    t2 = target[::2, ::2]
    if peak > base:
        extent = _footprint(np.where(target, g, base), at, base + EXTENT * (peak - base))
        keep = t2 & ~extent[::2, ::2]
        if keep.sum() >= MIN_LEFT * t2.sum():
            return g[::2, ::2][keep]
    keep = t2 & ~core[::2, ::2]
    return g[::2, ::2][keep] if keep.sum() >= 16 else g[::2, ::2][t2]


def detect_beam(image: np.ndarray, mask: np.ndarray | None = None, threshold: float = THRESHOLD) -> Presence:
    """The beam-presence decision (P1) for a grey image (rows, cols) and an optional bool
    target mask of the same shape (True = on the target). Pure; the image is not modified."""
    small, m, scale = pyramid(image, mask)
    target = np.ones(small.shape, bool) if m is None else m
    # At full resolution the plane is fitted to the image at its own precision: the analysis
    # that follows takes this very plane (controller.imaging.beam.analyze).
    plane = estimate_background(np.asarray(image) if scale == 1 else small, m)
    r = small - np.asarray(plane.evaluate(small.shape, np.float32), np.float32)
    r[~target] = 0.0  # off the target: the plane's level, so the smoothing does not leak it in
    sigma = min(SIGMA_PX, min(small.shape) / 16.0)
    g = cv2.GaussianBlur(r, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    # Within 2 σ of the view's edge g averages fewer independent pixels (the reflected border
    # repeats them): its spread is larger there, so the decision looks only further in.
    band = int(np.ceil(2.0 * sigma))
    inner = np.zeros(g.shape, bool)
    inner[band:g.shape[0] - band, band:g.shape[1] - band] = True
    inner = inner & target if inner.any() else target
    at = np.unravel_index(int(np.argmax(np.where(inner, g, -np.inf))), g.shape)
    peak = float(g[at])
    # Order statistics on every other row and column: g is smooth at σ = 4 px, so this loses
    # nothing and quarters the cost.
    base = median(g[::2, ::2][inner[::2, ::2]])
    fp = _footprint(np.where(target, g, base), at, base + 0.5 * (peak - base)) if peak > base else \
        np.zeros(g.shape, bool)
    rest = _background_sample(g, inner, at, base, peak, fp)
    floor = median(rest)
    spread = 1.4826 * median(np.abs(rest - floor))
    excess = peak - floor
    if not excess > 0.0:
        z = 0.0
    elif spread > 1e-6 * max(1.0, abs(plane.level)):
        z = excess / spread
    else:  # a noise-free synthetic image: any excess is a beam
        z = float("inf")
    bg = Background(level=plane.level, slope_x=plane.slope_x / scale, slope_y=plane.slope_y / scale,
                    noise=plane.noise)
    return Presence(beam=bool(z >= threshold), statistic=float(z), threshold=float(threshold),
                    peak_xy=(float(at[1] * scale), float(at[0] * scale)), level=scale, level_image=small,
                    smoothed=g,
                    footprint=fp, target=target, background=bg, spread=spread, floor=floor)
