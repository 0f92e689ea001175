"""A second independent error set: facet-wise ray sampling, where spot size blurs rather than zooms.

The first independent renderer (:mod:`independent_spots`) makes the spot size a zoom of the
aperture image and the source disc together. To guard the recognition's defaults against fitting
one renderer, this one makes different physics choices (written from first principles, no
``simplant`` import):

* **Facets.** A 3 x 3 array of rigid flat-canted facets, 1.2 x 1.0 m each with 5 cm gaps
  (3.7 x 3.1 m), at slant range D = 80 m, nearly focused: a ray from mirror point p lands at
  (1 − D/f)·p = −0.12·p (the image of the aperture, inverted, 12 % of its size) plus 2·D·s for a
  normal tilt s (rad): reflection doubles a tilt. Most error cases are tilts of *whole facets*
  (piecewise constant over the aperture, detached lobes): the lower-left facet mis-canted
  (8, 6) mrad, the outer columns canted apart ±8 mrad or drooping 8 mrad; wind-load is a
  torsion of the whole structure (vertical tilt 4 mrad per m of x, continuous).
* **Spot size is a convolution.** Each ray gets a source direction drawn from a limb-darkened sun
  disc, I(r) ∝ 1 − u(1 − √(1 − (r/R)²)), u = 0.6, R = 4.65 mrad (rejection sampling), and a
  Gaussian mirror slope error of σ = 1.0 mrad per axis (beam: 2σ). ``spot`` multiplies R and σ
  only; the aperture image and the facet lobes keep their size, so a larger spot is the same
  spot blurred, not zoomed.
* **Backlash rocks sinusoidally.** A worn azimuth drive swings the normal as b·sin(φ), φ
  uniform over the exposure, so the smear has the arcsine profile (bright ends), not a box.
* **Sensor.** 180 x 200 px (rows x cols), 4 cm per pixel at nominal framing, a 0.7 px Gaussian
  bloom, Poisson shot noise at a 1,500-count peak, Gaussian read noise σ = 3 and a radial
  (vignetting-shaped) pedestal.

``write_set(out, seed)`` writes ``library.csv`` (magnitudes 0.5, 1, 1.5 per case at the nominal
spot size and framing) and ``test.csv`` (magnitude uniform in 0.5–1.5, spot size ×0.7–1.4,
rotation 0–360°, zoom ×0.8–1.25, shift ±10 px, exposure ×0.5–1.6), columns
``image,label,az_deg,el_deg,magnitude,spot``: the manifests of ``heliocal library build`` /
``heliocal report confusion``. Images are float32 ``.npy`` (x = column, y = row).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from errorset_manifest import write_manifest_set

ROWS, COLS = 180, 200
FACET_M = (1.2, 1.0)  # w, h of one facet (m)
GAP_M = 0.05
SLANT_M = 80.0
IMAGE_SCALE = -0.12  # 1 - D/f: the aperture imaged inverted at 12 % (f ≈ 0.89 D)
SUN_RADIUS_RAD = 4.65e-3
LIMB_U = 0.6
SLOPE_SIGMA_RAD = 1.0e-3
PIXEL_M = 0.04
N_RAYS = 150_000

# Facet centres (m), column-major index k = 3 * col + row; col 0 = left (x < 0), row 0 = top (y > 0).
_CX = np.array([-1.0, 0.0, 1.0]) * (FACET_M[0] + GAP_M)
_CY = np.array([1.0, 0.0, -1.0]) * (FACET_M[1] + GAP_M)


def _facet_tilts(case: str, magnitude: float) -> np.ndarray:
    """Normal tilts (9, 2) in rad (x, y) of the nine facets for ``case`` at ``magnitude``."""
    cx = np.repeat(_CX, 3)
    t = np.zeros((9, 2))
    if case == "gravity-sag":  # the outer columns droop: a chevron of lobes
        t[:, 1] = -8e-3 * magnitude * np.abs(cx) / _CX[-1]
    elif case == "canting-error":  # the lower-left facet mis-canted
        t[2] = (8e-3 * magnitude, 6e-3 * magnitude)
    elif case == "facet-split":  # outer columns canted apart, the middle one true
        t[:, 0] = 8e-3 * magnitude * np.sign(cx)
    return t


TWIST_RAD_PER_M = 4e-3  # wind-load: d(tilt_y)/dx at magnitude 1
ROCK_RAD = {"gear-backlash": 8e-3}  # amplitude of the sinusoidal azimuth swing at magnitude 1
CASES = ("tracking-offset", "wind-load", "gear-backlash", "canting-error", "gravity-sag", "facet-split")


def _sun_offsets(rng: np.random.Generator, n: int, radius: float) -> np.ndarray:
    """n source directions (rad, (n, 2)) from a limb-darkened disc of ``radius`` (rejection sampling)."""
    out = np.empty((0, 2))
    while len(out) < n:
        r = radius * np.sqrt(rng.uniform(0, 1, 2 * n))
        keep = rng.uniform(0, 1, 2 * n) < 1.0 - LIMB_U * (1.0 - np.sqrt(1.0 - (r / radius) ** 2))
        a = rng.uniform(0, 2 * np.pi, 2 * n)
        out = np.vstack([out, np.column_stack([r * np.cos(a), r * np.sin(a)])[keep]])
    return out[:n]


def render(case: str, magnitude: float, rng: np.random.Generator, *, spot: float = 1.0,
           rotation_rad: float = 0.0, zoom: float = 1.0, shift_px=(0.0, 0.0),
           exposure: float = 1.0) -> np.ndarray:
    """One float32 image (ROWS, COLS) of ``case`` at ``magnitude``; ``spot`` widens the source disc
    and the slope error (a blur), ``zoom`` the pixel footprint, ``rotation_rad`` turns the image."""
    k = rng.integers(0, 9, N_RAYS)
    x = np.repeat(_CX, 3)[k] + rng.uniform(-0.5, 0.5, N_RAYS) * FACET_M[0]
    y = np.tile(_CY, 3)[k] + rng.uniform(-0.5, 0.5, N_RAYS) * FACET_M[1]
    tilt = _facet_tilts(case, magnitude)[k] + rng.normal(0.0, SLOPE_SIGMA_RAD * spot, (N_RAYS, 2))
    if case == "wind-load":  # torsion of the whole structure: the vertical tilt grows across the width
        tilt[:, 1] += TWIST_RAD_PER_M * magnitude * x
    src = _sun_offsets(rng, N_RAYS, SUN_RADIUS_RAD * spot)
    tx = IMAGE_SCALE * x + SLANT_M * (2.0 * tilt[:, 0] + src[:, 0])
    ty = IMAGE_SCALE * y + SLANT_M * (2.0 * tilt[:, 1] + src[:, 1])
    rock = ROCK_RAD.get(case, 0.0) * magnitude
    if rock:
        tx += 2.0 * SLANT_M * rock * np.sin(rng.uniform(0, 2 * np.pi, N_RAYS))
    c, s = np.cos(rotation_rad), np.sin(rotation_rad)
    pitch = PIXEL_M * zoom
    col = (c * tx + s * ty) / pitch + (COLS - 1) / 2 + shift_px[0]
    row = -(-s * tx + c * ty) / pitch + (ROWS - 1) / 2 + shift_px[1]  # target y up = image rows up
    img, _, _ = np.histogram2d(row, col, bins=(ROWS, COLS), range=[[-0.5, ROWS - 0.5], [-0.5, COLS - 0.5]])
    img = _bloom(img, 0.7)
    img *= 1500.0 * exposure / max(img.max(), 1e-12)
    yy, xx = np.mgrid[0:ROWS, 0:COLS]
    r2 = ((xx - COLS / 2) / COLS) ** 2 + ((yy - ROWS / 2) / ROWS) ** 2
    img += 30.0 * (1.0 - 0.8 * r2)  # stray light, brighter in the middle (vignetting shape)
    img = rng.poisson(img).astype(np.float64) + rng.normal(0.0, 3.0, img.shape)
    return img.astype(np.float32)


def _bloom(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (σ in px, kernel ±3σ) by FFT-free direct convolution per axis."""
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    img = np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), 0, img)
    return np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), 1, img)


def write_set(out: str | Path, seed: int = 0, views: int = 24,
              magnitudes=(0.5, 1.0, 1.5), spot_range=(0.7, 1.4)) -> tuple[Path, Path]:
    """Write ``out/library.csv`` and ``out/test.csv`` (``image,label,az_deg,el_deg,magnitude,spot``)."""
    return write_manifest_set(out, render, CASES, seed=seed, views=views, magnitudes=magnitudes,
                              spot_range=spot_range, stream=11, shift_px=10.0, exposure_range=(0.5, 1.6))
