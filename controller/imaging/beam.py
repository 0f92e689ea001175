"""Beam-spot analysis of a target image, as a chain of small steps.

1. :func:`controller.imaging.background.estimate_background` / ``subtract_background`` -
   ambient or pedestal removal
   (``"none"``, ``"auto"`` = sigma-clipped plane fit, or a null image of the same shape).
2. target mask - pixels outside a boolean mask are ignored.
3. :func:`segment` - threshold at a fraction of the peak; keep the connected region
   (8-connected) holding the most energy, so stray hot pixels and grid glints do not count.
4. intensity-weighted sub-pixel centroid, from :func:`controller.imaging.moments.central_moments`
   of the unsmoothed signal inside the region (ISO 11146-1 first-order moments); with
   ``background="fit"`` instead the centre of a spot model fitted with its background plane
   (:mod:`controller.imaging.spot_fit`), which needs no threshold.
5. peak and total of the background-subtracted spot.
6. :func:`second_moment_ellipse` - equivalent uniform ellipse.
7. :func:`enclosed_energy_diameter` - d90 about the centroid.
8. Hu moments of the segmented spot at unit mean intensity (:mod:`controller.imaging.moments`).

Conventions: image arrays are (rows, cols); x = column, y = row, in pixels, with (0, 0) the
centre of the top-left pixel. Intensities are in the image's own units (counts or relative
irradiance). Bad input raises :class:`controller.errors.InputError` with a one-line reason.

References
----------
.. [1] ISO 11146-1:2021, Lasers and laser-related equipment - Test methods for laser beam
   widths, divergence angles and beam propagation ratios (first and second moments, Sec. 3).
.. [2] OpenCSP spot analysis (Sandia), ``opencsp/common/lib/cv/spot_analysis`` - the step chain.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from controller.errors import InputError, NoBeamError
from controller.imaging.background import (
    Background,
    estimate_background,
    estimate_local_background,
    subtract_background,
    working_dtype,
)
from controller.imaging.moments import central_moments, hu_from_eta, normalised_central_moments
from controller.imaging.presence import Presence, detect_beam
from controller.imaging.spot_centroid import spot_centroid
from controller.imaging.spot_fit import SpotFit, SpotGuess, fit_spot

SMOOTH_PX = 1.0


@dataclass(frozen=True)
class Ellipse:
    """Uniform ellipse with the spot's second moments: full axis lengths in px, and the major
    axis angle in degrees from +x (column) towards +y (row, i.e. down the image), in (-90, 90]."""

    major_px: float
    minor_px: float
    angle_deg: float


@dataclass
class BeamResult:
    """Result of :func:`analyze`. ``hu`` has shape (7,); ``bbox`` is (row0, row1, col0, col1)
    of the segmented region (half-open); ``steps`` holds the intermediate images when asked."""

    centroid_px: tuple[float, float]
    peak: float
    total: float
    pixels: int
    hu: np.ndarray
    ellipse: Ellipse
    d90_px: float
    background: Background
    threshold_level: float
    saturated_pixels: int
    bbox: tuple[int, int, int, int]
    steps: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    spot_fit: SpotFit | None = None  # the model fit, with background="fit"
    presence: Presence | None = None  # the beam-presence decision (None: not asked for)
    clipped: tuple[str, ...] = ()  # edges of the view the spot runs out of (energy centroid)
    second_spot_px: tuple[float, float] | None = None  # another beam-like spot in view

    def as_dict(self) -> dict:
        """The CLI/JSON contract of ``heliocal beam``."""
        return {
            **(self.presence.as_dict() if self.presence is not None else {"beam": True}),
            "clipped": list(self.clipped),
            "second_spot_px": list(self.second_spot_px) if self.second_spot_px is not None else None,
            "centroid_px": [self.centroid_px[0], self.centroid_px[1]],
            "peak": self.peak,
            "total": self.total,
            "pixels": self.pixels,
            "hu": [float(v) for v in self.hu],
            "ellipse": {
                "major_px": self.ellipse.major_px,
                "minor_px": self.ellipse.minor_px,
                "angle_deg": self.ellipse.angle_deg,
            },
            "d90_px": self.d90_px,
            **({"spot_fit": self.spot_fit.as_dict()} if self.spot_fit is not None else {}),
        }


def check_image(image: np.ndarray) -> np.ndarray:
    """Validate a grey image for analysis; returns it as an ndarray (dtype kept).

    Rejects (InputError): not 2-D, empty, non-numeric, non-finite, constant (all zeros,
    all saturated), so that no later step divides by zero.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"expected a 2-D grey image, got shape {img.shape}")
    if img.size == 0 or min(img.shape) == 0:
        raise InputError("image is empty")
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise InputError(f"unsupported pixel type {img.dtype}")
    lo, hi = img.min(), img.max()
    if np.issubdtype(img.dtype, np.floating) and not (np.isfinite(lo) and np.isfinite(hi)):
        raise InputError("image contains NaN or infinite values")
    if hi == lo:
        if np.issubdtype(img.dtype, np.integer) and hi == np.iinfo(img.dtype).max:
            raise InputError(f"image is saturated: every pixel is {hi}")
        if hi == 0:
            raise InputError("image is all zeros: no beam")
        raise InputError(f"image is uniform (every pixel is {hi}): no beam")
    return img


def _candidate_window(image: np.ndarray, background: Background, threshold: float,
                      mask: np.ndarray | None) -> tuple[int, int, int, int]:
    """Window (row0, row1, col0, col1) that surely holds every pixel above the threshold.

    Found on a half-resolution Gaussian pyramid level (``cv2.pyrDown``, itself a 5x5 blur), with
    half the threshold and a 4 px margin, so that the full-resolution steps only touch the spot
    and not the whole frame. Small images (< 256 x 256) skip this and use the whole frame.
    """
    rows, cols = image.shape
    if image.size < 65_536:
        return 0, rows, 0, cols
    dt = working_dtype(image)
    half = cv2.pyrDown(np.asarray(image, dtype=dt))
    if background.image is not None:
        half -= cv2.pyrDown(background.image.astype(dt))
    elif background.is_constant:
        half -= dt(background.level)
    else:
        half -= background.on_grid(2.0 * np.arange(half.shape[1]), 2.0 * np.arange(half.shape[0]), dt)
    if mask is not None:
        half[~mask[::2, ::2][:half.shape[0], :half.shape[1]]] = -np.inf
    peak = float(half.max())
    if not peak > 0.0:
        return 0, rows, 0, cols
    above = half > 0.5 * threshold * peak
    r = np.flatnonzero(above.any(axis=1))
    c = np.flatnonzero(above.any(axis=0))
    return (max(0, 2 * int(r[0]) - 4), min(rows, 2 * int(r[-1]) + 6),
            max(0, 2 * int(c[0]) - 4), min(cols, 2 * int(c[-1]) + 6))


def segment(image: np.ndarray, background: Background, threshold: float, mask: np.ndarray | None = None,
            smooth_px: float = SMOOTH_PX) -> tuple[np.ndarray, float, float, tuple[int, int, int, int]]:
    """Threshold at ``threshold`` x peak and keep the most energetic 8-connected region.

    The threshold test runs on a Gaussian-smoothed copy (sigma ``smooth_px``, 5x5 kernel) so
    that one hot pixel, sensor noise or target texture neither sets the peak nor frays the
    region's edge; the moments later use the unsmoothed signal inside the region. Only a
    window around the candidate spot is processed at full resolution (:func:`_candidate_window`).

    Parameters
    ----------
    image : ndarray (rows, cols), raw intensities (any real dtype).
    background : the background model to subtract.
    threshold : fraction of the (smoothed, background-subtracted) peak in [0, 1).
    mask : optional bool target mask; pixels outside are ignored.
    smooth_px : Gaussian sigma in pixels for the threshold test; 0 disables smoothing.

    Returns
    -------
    (region, peak, level, bbox): ``region`` is a bool array over ``bbox`` (row0, row1, col0,
    col1); ``peak`` and ``level`` are the smoothed peak and the threshold level above the
    background.
    """
    dt = working_dtype(image)
    w0, w1, v0, v1 = _candidate_window(image, background, threshold, mask)
    shape = (w1 - w0, v1 - v0)
    work = np.array(image[w0:w1, v0:v1], dtype=dt)
    work -= background.evaluate(shape, dt, origin=(w0, v0))
    if smooth_px > 0:
        # Replicated border: the window edge lies below the threshold by construction.
        work = cv2.GaussianBlur(work, (5, 5), smooth_px, borderType=cv2.BORDER_REPLICATE)
    if mask is not None:
        work[~mask[w0:w1, v0:v1]] = -np.inf
    peak = float(work.max())
    if not peak > 0.0:
        raise InputError("no beam: nothing above the background")
    level = threshold * peak
    above = work > level
    rows_any = np.flatnonzero(above.any(axis=1))
    cols_any = np.flatnonzero(above.any(axis=0))
    bbox = (int(rows_any[0]), int(rows_any[-1]) + 1, int(cols_any[0]), int(cols_any[-1]) + 1)
    crop = above[bbox[0]:bbox[1], bbox[2]:bbox[3]]
    n, labels = cv2.connectedComponents(crop.view(np.uint8), connectivity=8)
    if n > 2:
        smooth_crop = work[bbox[0]:bbox[1], bbox[2]:bbox[3]]
        energy = np.bincount(labels.ravel(), weights=np.where(crop, smooth_crop, 0.0).ravel(), minlength=n)
        energy[0] = -np.inf
        region = labels == int(np.argmax(energy))
        r = np.flatnonzero(region.any(axis=1))
        c = np.flatnonzero(region.any(axis=0))
        sub = (int(r[0]), int(r[-1]) + 1, int(c[0]), int(c[-1]) + 1)
        region = region[sub[0]:sub[1], sub[2]:sub[3]]
        bbox = (bbox[0] + sub[0], bbox[0] + sub[1], bbox[2] + sub[2], bbox[2] + sub[3])
    else:
        region = crop
    return region, peak, level, (bbox[0] + w0, bbox[1] + w0, bbox[2] + v0, bbox[3] + v0)


def second_moment_ellipse(mu20: float, mu02: float, mu11: float, m00: float) -> Ellipse:
    """Uniform ellipse with the same second moments (ISO 11146-1 Sec. 3.3 style widths).

    With the covariance C = [[mu20, mu11], [mu11, mu02]] / m00 and eigenvalues l1 >= l2,
    a uniform ellipse of semi-axis a has variance a^2/4 along that axis, so the full axis
    lengths are 4 sqrt(l1) and 4 sqrt(l2). Angle = 0.5 atan2(2 mu11, mu20 - mu02).
    """
    a, c, b = mu20 / m00, mu02 / m00, mu11 / m00
    half_tr = 0.5 * (a + c)
    root = float(np.hypot(0.5 * (a - c), b))
    l1, l2 = half_tr + root, max(half_tr - root, 0.0)
    angle = float(np.degrees(0.5 * np.arctan2(2.0 * b, a - c)))
    if angle <= -90.0:
        angle += 180.0
    return Ellipse(major_px=4.0 * float(np.sqrt(l1)), minor_px=4.0 * float(np.sqrt(l2)), angle_deg=angle)


def enclosed_energy_diameter(weights: np.ndarray, cx: float, cy: float, fraction: float = 0.9,
                             bin_px: float = 0.02) -> float:
    """Diameter of the circle about (cx, cy) that holds ``fraction`` of the weights' energy.

    ``weights`` (rows, cols) with (cx, cy) in its own pixel frame. The radial energy profile is
    accumulated in bins of ``bin_px`` (O(n), no sort) and interpolated linearly inside the bin,
    so the result is within ``2 * bin_px`` of the exact pixel-sampled value.
    """
    ys, xs = np.nonzero(weights)
    w = weights[ys, xs]
    r = np.hypot(xs - cx, ys - cy)
    idx = (r / bin_px).astype(np.int64)
    prof = np.cumsum(np.bincount(idx, weights=w))
    goal = fraction * prof[-1]
    k = int(np.searchsorted(prof, goal))
    below = prof[k - 1] if k > 0 else 0.0
    frac_in_bin = (goal - below) / (prof[k] - below) if prof[k] > below else 1.0
    return 2.0 * bin_px * (k + frac_in_bin)


def _as_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.shape != shape:
        raise InputError(f"mask shape {m.shape} does not match image shape {shape}")
    m = m != 0
    if not m.any():
        raise InputError("target mask is empty (no pixel selected)")
    return m


def _background(img: np.ndarray, background, mask: np.ndarray | None) -> Background:
    if isinstance(background, Background):
        return background
    if isinstance(background, str):
        if background == "none":
            return Background(level=0.0)
        if background == "auto":
            return estimate_background(img, mask)
        raise InputError(f"background must be 'auto', 'local', 'fit', 'none' or an image, not {background!r}")
    null = np.asarray(background, dtype=np.float64)
    if null.shape != img.shape:
        raise InputError(f"background image shape {null.shape} does not match image shape {img.shape}")
    return Background(level=float(np.median(null)), image=null)


def _guess(img: np.ndarray, bg: Background, threshold: float, m: np.ndarray | None) -> SpotGuess:
    """Start of the spot-model fit: centroid, peak and second-moment widths of the segmented
    spot (a uniform ellipse's full axis is 4 sigma, :func:`second_moment_ellipse`)."""
    region, _, _, (r0, r1, c0, c1) = segment(img, bg, threshold, m)
    signal = np.array(img[r0:r1, c0:c1], dtype=np.float64) - bg.evaluate((r1 - r0, c1 - c0), origin=(r0, c0))
    weights = np.where(region, signal, 0.0)
    cm = central_moments(weights)
    if not cm.m00 > 0.0:
        raise InputError("no beam: segmented spot has no energy")
    ell = second_moment_ellipse(cm.mu["20"], cm.mu["02"], cm.mu["11"], cm.m00)
    return SpotGuess(x=cm.cx + c0, y=cm.cy + r0, peak=float(weights.max()), sigma_major_px=ell.major_px / 4,
                     sigma_minor_px=ell.minor_px / 4, angle_deg=ell.angle_deg)


def analyze(image: np.ndarray, threshold: float = 0.5, background="auto", mask: np.ndarray | None = None,
            keep_steps: bool = False, centroid: str = "energy", presence: bool = True) -> BeamResult:
    """Analyse a beam spot: presence, centroid, peak, total, ellipse, d90 and Hu moments.

    Parameters
    ----------
    image : ndarray (rows, cols), integer counts or float (HDR) intensities.
    threshold : fraction of the background-subtracted peak; pixels above it form the spot (its
        shape: ellipse, d90, Hu moments; and the centroid with ``centroid="segment"``).
    background : "auto" (sigma-clipped plane; with ``centroid="energy"`` a quadratic surface
        fitted around the spot, :mod:`controller.imaging.spot_centroid`), "local" (that plane
        refitted to a ring around the spot,
        :func:`controller.imaging.background.estimate_local_background`), "fit" (from the local
        plane, a quadratic background and an elliptical super-Gaussian fitted jointly by robust
        least squares over the same neighbourhood, :func:`controller.imaging.spot_fit.fit_spot`;
        the centroid is the model's centre, the rest is measured above the fitted surface),
        "none", a null image ndarray of the same shape, or a :class:`Background` estimated
        already (the same plane for several thresholds of one image: "auto"'s, computed once).
    mask : optional (rows, cols) target mask, non-zero = on target.
    keep_steps : keep intermediate images in ``result.steps`` for plotting.
    centroid : "energy" (default; with ``background="auto"``: the spot's full energy centroid
        in a symmetric window, no threshold) or "segment" (intensity centroid of the pixels
        above ``threshold``; the only one for "local", "none" and a null image).
    presence : decide first whether there is a beam at all (:func:`controller.imaging.presence.detect_beam`,
        on the image minus a null image when one is given) and raise
        :class:`controller.errors.NoBeamError` when there is none.

    Returns
    -------
    BeamResult with ``centroid_px == (x, y)`` (x = column, (0, 0) = centre of top-left pixel),
    ``hu`` of shape (7,) computed on the segmented spot scaled to unit mean intensity.
    """
    if not 0.0 <= float(threshold) < 1.0:
        raise InputError(f"threshold must be a fraction of the peak in [0, 1), got {threshold}")
    if centroid not in ("energy", "segment"):
        raise InputError(f"centroid must be 'energy' or 'segment', not {centroid!r}")
    img = check_image(image)
    m = _as_mask(mask, img.shape)
    fit = None
    auto = isinstance(background, str) and background == "auto"
    energy, pres = centroid == "energy" and auto, None
    if presence or energy:
        null = not isinstance(background, str)
        pres = detect_beam(subtract_background(img, _background(img, background, m)) if null else img, m)
        if presence and not pres.beam:
            raise NoBeamError(f"no beam: {pres.reason()}", pres.as_dict())
    # The energy centroid has its own surface around the spot; the shape (ellipse, d90, Hu
    # moments, which the recognition library was built on) stays above the plane over the view.
    spot = spot_centroid(img, pres, m) if energy else None
    if isinstance(background, str) and background in ("local", "fit"):
        # The ring plane only holds near the spot: analyse that neighbourhood only.
        bg, m = estimate_local_background(img, m)
        if background == "fit":
            fit = fit_spot(img, m, _guess(img, bg, float(threshold), m), bg)
            bg = fit.background
    elif auto and pres is not None and pres.level == 1:
        bg = pres.background  # the presence decision fitted this plane to these very pixels
    else:
        bg = _background(img, background, m)
    region, _, level, bbox = segment(img, bg, float(threshold), m)
    r0, r1, c0, c1 = bbox
    # A copy: for float64 input asarray would be a view, and the subtraction would write into
    # the caller's image.
    signal = np.array(img[r0:r1, c0:c1], dtype=np.float64)
    signal -= bg.evaluate((r1 - r0, c1 - c0), origin=(r0, c0))
    weights = np.where(region, signal, 0.0)
    peak = float(weights.max())
    cm = central_moments(weights)
    if not cm.m00 > 0.0:
        raise InputError("no beam: segmented spot has no energy")
    if spot is not None:
        cx, cy = spot.x, spot.y
    else:
        cx, cy = (cm.cx + c0, cm.cy + r0) if fit is None else (fit.x, fit.y)
    ell = second_moment_ellipse(cm.mu["20"], cm.mu["02"], cm.mu["11"], cm.m00)
    d90 = enclosed_energy_diameter(weights, cx - c0, cy - r0)
    pixels = int(np.count_nonzero(region))
    # Unit mean intensity over the spot: eta scales as mean^-(p+q)/2 (see moments.normalise_intensity).
    hu = hu_from_eta(normalised_central_moments(cm.scaled(pixels / cm.m00)))
    saturated = 0
    if np.issubdtype(img.dtype, np.integer):
        saturated = int(np.count_nonzero(img[r0:r1, c0:c1][region] == np.iinfo(img.dtype).max))
    steps: dict[str, np.ndarray] = {}
    if keep_steps:
        full = subtract_background(img, bg)
        full_region = np.zeros(img.shape, bool)
        full_region[r0:r1, c0:c1] = region
        steps = {
            "input": np.asarray(img, dtype=np.float64),
            "background": np.broadcast_to(np.asarray(bg.evaluate(img.shape), dtype=np.float64), img.shape),
            "subtracted": full,
            "mask": np.ones(img.shape, bool) if m is None else m,
            "threshold": full > level,
            "spot": np.where(full_region, full, 0.0),
        }
    return BeamResult(
        centroid_px=(float(cx), float(cy)), peak=peak, total=float(cm.m00), pixels=pixels, hu=hu,
        ellipse=ell, d90_px=d90, background=bg, threshold_level=level, saturated_pixels=saturated,
        bbox=bbox, steps=steps, spot_fit=fit, presence=pres,
        clipped=spot.clipped if spot is not None else (),
        second_spot_px=spot.second_spot if spot is not None else None,
    )


