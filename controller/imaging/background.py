"""The background under a beam image: ambient light or a sensor pedestal, as a plane (or a
null image), estimated robustly and subtracted.

Conventions: image arrays are (rows, cols); x = column, y = row, in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.errors import InputError

# Subsample the background estimate to about this many pixels: a plane has 3 unknowns.
_BACKGROUND_SAMPLES = 2048
_CLIP_SIGMA = 3.0


@dataclass(frozen=True)
class Background:
    """Background model b(x, y) = level + slope_x * x + slope_y * y (counts, counts/px)."""

    level: float
    slope_x: float = 0.0
    slope_y: float = 0.0
    noise: float = 0.0  # robust standard deviation of the background pixels
    image: np.ndarray | None = None  # a full null image, when one was given

    @property
    def is_constant(self) -> bool:
        return self.image is None and self.slope_x == 0.0 and self.slope_y == 0.0

    def evaluate(self, shape: tuple[int, int], dtype=np.float64, origin: tuple[int, int] = (0, 0)
                 ) -> np.ndarray | float:
        """b(x, y) over a (rows, cols) window whose top-left pixel is ``origin`` (row, col)."""
        if self.image is not None:
            return self.image[origin[0]:origin[0] + shape[0], origin[1]:origin[1] + shape[1]].astype(dtype)
        if self.is_constant:
            return self.level
        y = np.arange(origin[0], origin[0] + shape[0], dtype=dtype)
        x = np.arange(origin[1], origin[1] + shape[1], dtype=dtype)
        return (self.level + self.slope_y * y)[:, None] + (self.slope_x * x)[None, :]


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
    coef = np.array([np.median(v), 0.0, 0.0])
    sigma = 0.0
    use = np.ones(v.size, bool)
    for _ in range(iterations):
        resid = v - (coef[0] + coef[1] * x + coef[2] * y)
        r_use = resid[use]
        sigma = 1.4826 * float(np.median(np.abs(r_use - np.median(r_use))))
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
        level = float(np.median(v[use])) if use.any() else float(coef[0])
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
