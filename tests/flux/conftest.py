"""Synthetic truth for the flux tests: a limb-darkened Sun and a Lambertian target rendered
through the camera model (simplant.devices.sensor.SensorModel).

Camera radiometry used by the renderers: a pixel collects K · T · L̄ · Ω_px counts per second,
with K the camera constant, T the ND transmittance, L̄ the scene radiance averaged over the
pixel's footprint and Ω_px = tan²(γ/2)/r_sun_px² its solid angle. The Sun's mean radiance is
DNI / (π tan²(γ/2)), so its disc sums to K · T · DNI; a Lambertian target of reflectivity ρ
under irradiance E has L = ρE/π. Footprints are integrated by 8×8 supersampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from simplant.devices.sensor import SensorModel

GAMMA = 9.3e-3
SUPER = 8


def _subpixel_grid(shape: tuple[int, int], s: int = SUPER) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = shape
    y = (np.arange(rows * s) + 0.5) / s - 0.5
    x = (np.arange(cols * s) + 0.5) / s - 0.5
    return np.meshgrid(x, y)


def _bin(a: np.ndarray, shape: tuple[int, int], s: int = SUPER) -> np.ndarray:
    return a.reshape(shape[0], s, shape[1], s).mean(axis=(1, 3))


def limb_darkened_disc(shape, center, radius, u=0.6) -> np.ndarray:
    """Pixel-averaged disc with linear limb darkening I(μ) = 1 - u (1 - μ), 0 outside."""
    xx, yy = _subpixel_grid(shape)
    rho2 = ((xx - center[0]) ** 2 + (yy - center[1]) ** 2) / radius**2
    mu = np.sqrt(np.clip(1.0 - rho2, 0.0, 1.0))
    return _bin(np.where(rho2 < 1.0, 1.0 - u * (1.0 - mu), 0.0), shape)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: image shape, sun radius in pixels (sets the IFOV), camera constant K
    (counts per second per W/m²/sr per sr), sensor."""

    shape: tuple[int, int] = (200, 260)
    sun_radius_px: float = 40.0
    k: float = 9.0e7
    sensor: SensorModel = SensorModel()

    @property
    def omega_px(self) -> float:
        return np.tan(GAMMA / 2) ** 2 / self.sun_radius_px**2

    @property
    def ifov(self) -> float:
        return np.tan(GAMMA / 2) / self.sun_radius_px

    def sun_rate(self, dni, transmittance, center=None, u=0.6) -> np.ndarray:
        """Counts per second of a sun image (background 0)."""
        c = center or ((self.shape[1] - 1) / 2 + 0.3, (self.shape[0] - 1) / 2 - 0.2)
        disc = limb_darkened_disc(self.shape, c, self.sun_radius_px, u)
        return self.k * transmittance * dni * disc / disc.sum()

    def target_rate(self, field, reflectivity, distance_m, view_angle_rad, transmittance=1.0,
                    center_px=None) -> np.ndarray:
        """Counts per second of a Lambertian target with irradiance field(u, v) (W/m², metres
        on the target), seen at distance r and view angle θ (foreshortened along x)."""
        cx, cy = center_px or ((self.shape[1] - 1) / 2, (self.shape[0] - 1) / 2)
        xx, yy = _subpixel_grid(self.shape)
        scale = distance_m * self.ifov
        u = (xx - cx) * scale / np.cos(view_angle_rad)
        v = (yy - cy) * scale
        e = _bin(field(u, v), self.shape)
        return self.k * transmittance * reflectivity * e / np.pi * self.omega_px

    def truth(self, field, distance_m, view_angle_rad, center_px=None) -> np.ndarray:
        """The irradiance field averaged over each pixel's footprint, W/m² (rows, cols)."""
        cx, cy = center_px or ((self.shape[1] - 1) / 2, (self.shape[0] - 1) / 2)
        xx, yy = _subpixel_grid(self.shape)
        s = distance_m * self.ifov
        return _bin(field((xx - cx) * s / np.cos(view_angle_rad), (yy - cy) * s), self.shape)

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Sub-pixel centre coordinates (x, y), shape (rows·8, cols·8)."""
        return _subpixel_grid(self.shape)

    def bin(self, a: np.ndarray) -> np.ndarray:
        """Average a sub-pixel array to pixels."""
        return _bin(a, self.shape)

    def expose(self, rate, exposure_s, rng) -> np.ndarray:
        return self.sensor.expose(rate, exposure_s, rng)


def gaussian_beam(peak_w_m2=600e3, sigma_m=0.35, second=(0.6, -0.2, 0.4, 0.25)):
    """Two-lobed irradiance field (W/m²) on the target and its exact total power (W).

    second = (u0, v0, relative peak, sigma) of a side lobe.
    """
    u0, v0, rel, s2 = second

    def field(u, v):
        return peak_w_m2 * (np.exp(-(u**2 + v**2) / (2 * sigma_m**2))
                            + rel * np.exp(-((u - u0) ** 2 + (v - v0) ** 2) / (2 * s2**2)))

    power = peak_w_m2 * 2 * np.pi * (sigma_m**2 + rel * s2**2)
    return field, power


@pytest.fixture(scope="session")
def camera() -> Camera:
    return Camera()


@pytest.fixture(scope="session")
def beam():
    """gaussian_beam(peak_w_m2=..., sigma_m=..., second=...) -> (field, exact power W)."""
    return gaussian_beam


@pytest.fixture(scope="session")
def disc_renderer():
    """limb_darkened_disc(shape, (x, y), radius, u=0.6) -> pixel-averaged disc."""
    return limb_darkened_disc


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20260807)
