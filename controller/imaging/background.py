"""The background under a beam image: ambient light or a sensor pedestal, as a plane (or a
null image), estimated robustly and subtracted.

Conventions: image arrays are (rows, cols); x = column, y = row, in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from controller.errors import InputError

# Subsample the background estimate to about this many pixels: a plane has 3 unknowns.
_BACKGROUND_SAMPLES = 2048
_CLIP_SIGMA = 3.0
# The ring background searches images larger than this (px, either side) on a pyramid level.
_LOCAL_MAX_SIDE = 320


def median(values: np.ndarray) -> float:
    """The median of the finite 1-D array ``values`` as :func:`numpy.median` gives it (the mean
    of the two middle values of an even count; NaN when empty), from one partial sort: a beam's
    analysis takes about twenty medians of a few thousand samples, and ``numpy.median``'s own
    checks cost more than the sort (issue 42)."""
    n = values.size
    if not n:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(values, k)[k])
    low, high = np.partition(values, (k - 1, k))[k - 1:k + 1]
    return float((low + high) / 2)


@dataclass(frozen=True)
class Background:
    """Background model b(x, y) = level + slope_x x + slope_y y
    + c_xx (x − x0)² + c_yy (y − y0)² + c_xy (x − x0)(y − y0), with ``quad`` = (c_xx, c_yy, c_xy)
    about ``centre`` = (x0, y0) (counts, counts/px, counts/px²; zero for a plane)."""

    level: float
    slope_x: float = 0.0
    slope_y: float = 0.0
    noise: float = 0.0  # robust standard deviation of the background pixels
    image: np.ndarray | None = None  # a full null image, when one was given
    quad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    centre: tuple[float, float] = (0.0, 0.0)

    @property
    def is_constant(self) -> bool:
        return self.image is None and self.slope_x == 0.0 and self.slope_y == 0.0 and not any(self.quad)

    def evaluate(self, shape: tuple[int, int], dtype=np.float64, origin: tuple[int, int] = (0, 0)
                 ) -> np.ndarray | float:
        """b(x, y) over a (rows, cols) window whose top-left pixel is ``origin`` (row, col)."""
        if self.image is not None:
            return self.image[origin[0]:origin[0] + shape[0], origin[1]:origin[1] + shape[1]].astype(dtype)
        if self.is_constant:
            return self.level
        y = np.arange(origin[0], origin[0] + shape[0], dtype=dtype)
        x = np.arange(origin[1], origin[1] + shape[1], dtype=dtype)
        return self.on_grid(x, y, dtype)

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """b at the points (``x``, ``y``) (px, arrays of one shape and dtype; no null image)."""
        out = self.level + self.slope_x * x + self.slope_y * y
        if any(self.quad):
            cxx, cyy, cxy = self.quad
            u, v = x - self.centre[0], y - self.centre[1]
            out = out + cxx * u * u + cyy * v * v + cxy * u * v
        return out.astype(x.dtype, copy=False)

    def on_grid(self, x: np.ndarray, y: np.ndarray, dtype=np.float64) -> np.ndarray:
        """b at the pixel centres of columns ``x`` and rows ``y`` (1-D, px): (len(y), len(x))."""
        x = np.asarray(x, dtype)
        y = np.asarray(y, dtype)
        out = (self.level + self.slope_y * y)[:, None] + (self.slope_x * x)[None, :]
        if any(self.quad):
            cxx, cyy, cxy = self.quad
            u, v = x - dtype(self.centre[0]), y - dtype(self.centre[1])
            out = out + (cyy * v * v)[:, None] + (cxx * u * u)[None, :] + cxy * v[:, None] * u[None, :]
        return out.astype(dtype, copy=False)


def estimate_background(image: np.ndarray, mask: np.ndarray | None = None, iterations: int = 3) -> Background:
    """Sigma-clipped least-squares plane through the background pixels.

    On a subsampled grid (about 2,000 samples - a plane has 3 unknowns), repeat: fit
    b = a + bx*x + by*y to the kept pixels; robust sigma = 1.4826 * MAD of the residuals; keep
    pixels with |residual| <= 3 sigma. This rejects the spot (upper tail) and dark grid lines or
    fiducials (lower tail). It needs the spot to cover less than about half of the (masked)
    image. A plane whose variation over the image stays below one noise sigma is reported as a
    constant (the median of the kept samples).
    """
    rows, cols = image.shape
    step = max(1, int(np.sqrt(image.size / _BACKGROUND_SAMPLES)))
    sub = np.asarray(image[::step, ::step], dtype=np.float64)
    ys, xs = np.mgrid[0:rows:step, 0:cols:step]
    keep = np.ones(sub.shape, bool) if mask is None else np.asarray(mask[::step, ::step], bool)
    v, x, y = sub[keep], xs[keep].astype(np.float64), ys[keep].astype(np.float64)
    if v.size < 3:
        raise InputError("target mask leaves fewer than 3 background pixels")
    coef = np.array([median(v), 0.0, 0.0])
    sigma = 0.0
    use = np.ones(v.size, bool)
    for _ in range(iterations):
        resid = v - (coef[0] + coef[1] * x + coef[2] * y)
        r_use = resid[use]
        sigma = 1.4826 * median(np.abs(r_use - median(r_use)))
        use = np.abs(resid) <= max(_CLIP_SIGMA * sigma, 1e-12 * max(1.0, abs(coef[0])))
        if use.sum() < 3:
            break
        # 3x3 normal equations from plain sums: far cheaper than a least-squares solver.
        xu, yu, vu = x[use], y[use], v[use]
        sx, sy = xu.sum(), yu.sum()
        sxy = float(np.dot(xu, yu))
        ata = np.array([[xu.size, sx, sy], [sx, np.dot(xu, xu), sxy], [sy, sxy, np.dot(yu, yu)]])
        coef = np.linalg.solve(ata + 1e-12 * np.eye(3), [vu.sum(), np.dot(xu, vu), np.dot(yu, vu)])
    span = abs(coef[1]) * (cols - 1) + abs(coef[2]) * (rows - 1)
    if span <= sigma:
        level = median(v[use]) if use.any() else float(coef[0])
        return Background(level=level, noise=sigma)
    return Background(level=float(coef[0]), slope_x=float(coef[1]), slope_y=float(coef[2]), noise=sigma)


def working_dtype(image: np.ndarray) -> type:
    """float64 for float64 input, else float32: frame-wide steps stay cheap; moments are summed
    in float64 on the small crop around the spot."""
    return np.float64 if image.dtype == np.float64 else np.float32


def subtract_background(image: np.ndarray, background: Background) -> np.ndarray:
    """Background-subtracted image (float32, or float64 for float64 input)."""
    dt = working_dtype(image)
    return np.asarray(image, dtype=dt) - background.evaluate(image.shape, dt)


def _distance_to(region: np.ndarray) -> np.ndarray:
    """Euclidean distance (px, float32) of every pixel to the nearest pixel of ``region``:
    one distance transform instead of a dilation per radius."""
    return cv2.distanceTransform((~region.astype(bool)).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def _largest(above: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The 8-connected region of ``above`` holding the most ``weight``."""
    n, labels = cv2.connectedComponents(above.astype(np.uint8), connectivity=8)
    energy = np.bincount(labels.ravel(), weights=np.where(above, weight, 0.0).ravel(), minlength=n)
    energy[0] = -np.inf
    return labels == int(np.argmax(energy))


def _footprint(g: np.ndarray, fraction: float) -> np.ndarray | None:
    """The spot's footprint in the smoothed signal ``g``: the core is the most energetic region
    above half its peak; the footprint is the region above ``fraction`` × the core's peak that
    holds that peak, within the core's equivalent-circle radius of the core."""
    peak = float(g.max())
    if not peak > 0.0:
        return None
    core = _largest(g > 0.5 * peak, g)
    r, c = np.unravel_index(int(np.argmax(np.where(core, g, -np.inf))), g.shape)
    _, labels = cv2.connectedComponents((g > fraction * g[r, c]).astype(np.uint8), connectivity=8)
    # Bounded by the core grown by its equivalent radius, so that a background structure above
    # the low threshold and touching the spot does not join the footprint.
    reach = _distance_to(core) <= np.sqrt(core.sum() / np.pi)
    return (labels == labels[r, c]) & reach


def estimate_local_background(image: np.ndarray, mask: np.ndarray | None = None, spot_fraction: float = 0.2,
                              inner: float = 0.25, outer: float = 0.75, smooth_px: float = 3.0,
                              iterations: int = 2) -> tuple[Background, np.ndarray]:
    """A plane fitted only to a ring of pixels around the spot, for backgrounds one plane over
    the whole view cannot follow (vignetting, shadow edges, a lit patch elsewhere); returns the
    plane and the bool neighbourhood (rows, cols) where it holds.

    Start from :func:`estimate_background`; then ``iterations`` times: smooth the
    background-free image (Gaussian, σ = ``smooth_px``), find the spot's footprint (the region
    above ``spot_fraction`` × the spot's peak around the most energetic region above half the
    peak), and refit the sigma-clipped plane to the ring between ``inner`` and ``outer`` times
    the footprint's equivalent radius r = √(area/π) outside it (within ``mask`` if given): the
    ring scales with the spot, so a broad halo stays inside it. The neighbourhood is the
    footprint grown by ``outer`` · r: outside it the plane is an extrapolation, so analysis
    should be restricted to it. Keeps the previous plane if the ring has too few pixels.

    Images larger than 320 px on a side are searched on a Gaussian pyramid level
    (``cv2.pyrDown``, pixel x_full = 2^k x_level; σ scaled alike) and the plane's
    slopes divided by 2^k; ``noise`` is measured at full resolution on the ring.
    """
    img = np.asarray(image, dtype=np.float32)
    mask = None if mask is None else np.asarray(mask) != 0
    small, small_mask, scale = img, mask, 1
    while max(small.shape) > _LOCAL_MAX_SIDE:
        small = cv2.pyrDown(small)
        scale *= 2
        if small_mask is not None:
            small_mask = small_mask[::2, ::2]
    bg, near, ring = _ring_plane(small, small_mask, spot_fraction, inner, outer, smooth_px / scale,
                                 iterations)
    if scale == 1:
        return bg, near
    rows, cols = img.shape

    def full(m: np.ndarray) -> np.ndarray:
        up = cv2.resize(m.view(np.uint8), (cols, rows), interpolation=cv2.INTER_NEAREST) > 0
        return up if mask is None else up & mask

    bg = Background(level=bg.level, slope_x=bg.slope_x / scale, slope_y=bg.slope_y / scale)
    ring_full = full(ring)
    if ring_full.any():
        resid = (img - bg.evaluate(img.shape, np.float32))[ring_full]
        bg = Background(bg.level, bg.slope_x, bg.slope_y,
                        noise=1.4826 * median(np.abs(resid - median(resid))))
    return bg, full(near)


def _ring_plane(img: np.ndarray, mask: np.ndarray | None, spot_fraction: float, inner: float, outer: float,
                smooth_px: float, iterations: int) -> tuple[Background, np.ndarray, np.ndarray]:
    """The loop of :func:`estimate_local_background` at one resolution: (plane, neighbourhood,
    last ring)."""
    bg = estimate_background(img, mask)
    near = np.ones(img.shape, bool) if mask is None else np.asarray(mask, bool)
    ring = np.zeros(img.shape, bool)
    for _ in range(iterations):
        signal = img - np.asarray(bg.evaluate(img.shape, np.float32), np.float32)
        g = cv2.GaussianBlur(signal, (0, 0), smooth_px)
        g[~near] = 0.0  # after the first pass the plane is only valid near the spot
        spot = _footprint(g, spot_fraction)
        if spot is None:
            break
        r_eq = float(np.sqrt(np.count_nonzero(spot) / np.pi))  # footprint's equivalent radius
        dist = _distance_to(spot)
        hood = dist <= outer * r_eq
        new_ring = hood & (dist > inner * r_eq)
        if mask is not None:
            new_ring &= mask
            hood &= mask
        try:
            bg = estimate_background(img, new_ring)
        except InputError:  # ring outside the mask or the view: keep the last plane
            break
        near, ring = hood, new_ring
    return bg, near, ring
