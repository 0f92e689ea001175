"""An error set rendered without the project's optics: the recognition's independent check.

The hidden evaluation of issue #14 renders its own spots; to measure whether the library's
defaults generalise rather than fit :mod:`simplant.optics`, this module renders beam spots from
a separate, paraxial model written here from first principles (no ``simplant`` import):

* A focusing mirror of w x h (m) at slant range D (m) with focal length f reflects a ray from
  mirror point (x, y) to the target point (x, y)·(1 − D/f) + 2·D·s(x, y), with s the surface
  slope error (rad): the law of reflection doubles a slope, and a lens-like mirror images its
  aperture at scale (1 − D/f) in the target plane (small angles, target normal to the beam).
* The source of angular diameter θ adds to every ray a point uniformly distributed in a disc of
  radius D·θ/2 (the sun-shape/lamp image); the camera adds a Gaussian blur of σ_cam.
  "Spot size" = the source disc and the aperture image scale together.
* A worn azimuth gear rocks the mirror during the exposure: the normal sweeps a band b (rad)
  in azimuth, the beam 2b, so the spot is smeared uniformly over 2·D·b along x.

Cases are slope fields of the same mechanisms as the project's error set but parametrised
independently (``CASES``). Each image: ray landing points histogrammed onto a 160 x 160 px
grid turned by a random angle, zoomed and shifted, exposure-scaled, with Poisson shot noise,
Gaussian read noise and a dim sloping pedestal; written as float32 ``.npy``.

``write_set(out, seed)`` writes ``library.csv`` (3 magnitudes 0.5, 1, 1.5 per case at the
nominal spot size) and ``test.csv`` (magnitude uniform in 0.5-1.5, spot size x0.7-1.4, framing
and noise random): the manifests of ``heliocal library build`` / ``heliocal report confusion``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from errorset_manifest import write_manifest_set

PX = 160
MIRROR_M = (3.0, 2.4)  # w, h of the mirror (m); not the demo heliostat's 3.2 x 2.56
SLANT_M = 60.0
APERTURE_SCALE = 0.3  # 1 - D/f: the target sees the aperture at 30 % (f ≈ 1.43 D)
SOURCE_MRAD = 12.0  # angular diameter of the source at nominal spot size
PIXEL_M = 0.05  # nominal pixel footprint on the target (m)
N_RAYS = 120_000


def _twist(x, y, m):
    return 5e-3 * m * y, 0.0 * y


def _sag(x, y, m):
    return 0.0 * x, m * y / 250.0


def _canting(x, y, m):
    on = (x < 0) & (y > 0)  # upper-left quadrant (the project's tilts the upper right)
    return np.where(on, 5e-3 * m, 0.0), np.where(on, -5e-3 * m, 0.0)


def _split(x, y, m):
    return np.where(x > 0, 5e-3 * m, -5e-3 * m), 0.0 * y


def _none(x, y, m):
    return 0.0 * x, 0.0 * y


# label: (slope field, azimuth rock band at magnitude 1 (rad))
CASES = {
    "tracking-offset": (_none, 0.0),
    "wind-load": (_twist, 0.0),
    "gear-backlash": (_none, 25e-3),
    "canting-error": (_canting, 0.0),
    "gravity-sag": (_sag, 0.0),
    "facet-split": (_split, 0.0),
}


def render(case: str, magnitude: float, rng: np.random.Generator, *, spot: float = 1.0,
           rotation_rad: float = 0.0, zoom: float = 1.0, shift_px=(0.0, 0.0),
           exposure: float = 1.0) -> np.ndarray:
    """One HDR-like float image (rows, cols) of ``case`` at ``magnitude`` (x = column, y = row).

    ``spot`` scales the source disc and the aperture image (spot size), ``zoom`` the pixel
    footprint (framing), ``rotation_rad`` turns the image axes about the aim point.
    """
    slopes, rock = CASES[case]
    w, h = MIRROR_M
    x = rng.uniform(-w / 2, w / 2, N_RAYS)
    y = rng.uniform(-h / 2, h / 2, N_RAYS)
    sx, sy = slopes(x, y, magnitude)
    tx = APERTURE_SCALE * spot * x + 2.0 * SLANT_M * sx
    ty = APERTURE_SCALE * spot * y + 2.0 * SLANT_M * sy
    r = 0.5 * SLANT_M * SOURCE_MRAD * 1e-3 * spot * np.sqrt(rng.uniform(0, 1, N_RAYS))
    a = rng.uniform(0, 2 * np.pi, N_RAYS)
    tx += r * np.cos(a)
    ty += r * np.sin(a)
    if rock:
        tx += 2.0 * SLANT_M * rock * magnitude * rng.uniform(-0.5, 0.5, N_RAYS)
    c, s = np.cos(rotation_rad), np.sin(rotation_rad)
    pitch = PIXEL_M * zoom
    col = (c * tx + s * ty) / pitch + (PX - 1) / 2 + shift_px[0]
    row = -(-s * tx + c * ty) / pitch + (PX - 1) / 2 + shift_px[1]  # target y up = image rows up
    img, _, _ = np.histogram2d(row, col, bins=PX, range=[[-0.5, PX - 0.5], [-0.5, PX - 0.5]])
    img = _blur(img, 1.0)
    img *= 4000.0 * exposure / max(img.max(), 1e-12)
    yy, xx = np.mgrid[0:PX, 0:PX]
    img += 20.0 + 8.0 * xx / PX + 4.0 * yy / PX  # stray-light pedestal with a gradient
    img = rng.poisson(img).astype(np.float64) + rng.normal(0.0, 2.0, img.shape)
    return img.astype(np.float32)


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (camera PSF), σ in px, kernel ±3σ, zero beyond the frame."""
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    img = np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), 0, img)
    return np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), 1, img)


def write_set(out: str | Path, seed: int = 0, views: int = 12,
              magnitudes=(0.5, 1.0, 1.5), spot_range=(0.7, 1.4)) -> tuple[Path, Path]:
    """Write ``out/library.csv`` and ``out/test.csv`` (``image,label,az_deg,el_deg,magnitude,spot``)."""
    return write_manifest_set(out, render, CASES, seed=seed, views=views, magnitudes=magnitudes,
                              spot_range=spot_range, stream=1, shift_px=8.0, exposure_range=(0.6, 1.5))
