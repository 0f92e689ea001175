"""Aiming a heliostat: the bisector law, specular reflection, ray/plane intersection, errors.

All vectors are ENU (east, north, up), positions in metres, shape (3,) or broadcastable
(..., 3). ``source_dir`` is the unit vector from the heliostat *towards* the light source
(sun or lamp); a ray's ``direction`` is the way light travels.

References
----------
.. [1] W. B. Stine and M. Geyer, "Power From The Sun", 2001, Ch. 8 ("heliostat field"):
   the mirror normal bisects the directions to the sun and to the aim point.
.. [2] M. Born and E. Wolf, "Principles of Optics", 7th ed., Sec. 1.5: law of reflection
   r = d − 2 (d·n) n.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np

from controller.errors import InputError
from controller.geometry.vectors import azel_to_vector, cross, norm, unit


def aim_normal(source_dir, heliostat_pos, aim_point) -> np.ndarray:
    """Mirror normal that reflects light from ``source_dir`` onto ``aim_point``.

    n = (ŝ + t̂) / |ŝ + t̂|, with ŝ the unit vector to the source and t̂ the unit vector from
    ``heliostat_pos`` (the mirror centre, m ENU) to ``aim_point`` (m ENU) [1]_. Shape (..., 3).
    """
    to_target = unit(np.asarray(aim_point, dtype=float) - np.asarray(heliostat_pos, dtype=float))
    return unit(unit(source_dir) + to_target)


def reflect(direction, normal) -> np.ndarray:
    """Specular reflection r = d − 2 (d·n̂) n̂ of a ray travelling along ``direction`` [2]_.

    Works for either orientation of ``normal``; the length of ``direction`` is kept.
    """
    d = np.asarray(direction, dtype=float)
    n = unit(normal)
    return d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n


def reflected_beam(source_dir, normal) -> np.ndarray:
    """Unit direction of the beam reflected by a mirror with ``normal`` lit from ``source_dir``."""
    return reflect(-unit(source_dir), normal)


def intersect_plane(origin, direction, plane_point, plane_normal) -> np.ndarray:
    """Point where the ray origin + t·direction (t ≥ 0) meets a plane. Shape (3,).

    t = ((p₀ − o)·n) / (d·n). Raises ValueError when the ray is parallel to the plane or the
    plane lies behind the ray (t < 0).
    """
    o = np.asarray(origin, dtype=float)
    d = np.asarray(direction, dtype=float)
    n = np.asarray(plane_normal, dtype=float)
    denom = float(np.dot(d, n))
    if abs(denom) < 1e-12 * np.linalg.norm(d) * np.linalg.norm(n):
        raise ValueError("ray is parallel to the plane")
    t = float(np.dot(np.asarray(plane_point, dtype=float) - o, n)) / denom
    if t < 0.0:
        raise ValueError("the plane lies behind the ray")
    return o + t * d


def source_direction(source, heliostat_pos, *, when: datetime | None = None, site=None) -> np.ndarray:
    """Unit ENU vector from a heliostat towards a configured light source. Shape (3,).

    Parameters
    ----------
    source : controller.config.SunSource or LampSource
        The sun (direction from NREL SPA, needs ``when`` and ``site``) or a lamp (direction
        to its ``position_enu_m``; parallax matters, so ``heliostat_pos`` is used).
    heliostat_pos : array (3,)
        Mirror centre, m ENU.
    when : datetime, optional
        Time for the sun (naive = UTC).
    site : controller.config.Site, optional
        Site whose latitude, longitude, elevation, pressure, temperature and ΔT feed SPA.
    """
    kind = getattr(source, "kind", None)
    if kind == "lamp":
        return unit(np.asarray(source.position_enu_m, dtype=float) - np.asarray(heliostat_pos, dtype=float))
    if kind == "sun":
        if when is None or site is None:
            raise InputError(f"light source {source.id!r} is the sun: a time and a site are needed")
        from controller.geometry.sun import solar_position

        pos = solar_position(when, site.latitude_deg, site.longitude_deg, site.elevation_m,
                             site.pressure_mbar, site.temperature_c, site.delta_t_s)
        return azel_to_vector(pos.azimuth_deg, pos.elevation_deg)
    raise InputError(f"unknown light source kind {kind!r}")


def angle_mrad(u, v) -> np.ndarray:
    """Angle between directions u and v, mrad (atan2 form, accurate at small angles)."""
    a, b = unit(u), unit(v)
    return 1e3 * np.arctan2(norm(cross(a, b))[..., 0], np.sum(a * b, axis=-1))


def normal_error_mrad(normal, reference_normal) -> np.ndarray:
    """Mirror-normal error, mrad: the angle between two normals (half the beam error in the
    plane of incidence)."""
    return angle_mrad(normal, reference_normal)


def beam_error_mrad(source_dir, normal, reference_normal) -> np.ndarray:
    """Beam pointing error, mrad: angle between the beams reflected by ``normal`` and by
    ``reference_normal`` for light from ``source_dir``. Twice the normal error for a tilt in the
    plane of incidence, 2·δ·cos(θᵢ) for a tilt across it."""
    return angle_mrad(reflected_beam(source_dir, normal), reflected_beam(source_dir, reference_normal))


def pointing_error_mrad(heliostat_pos, aim_point, spot_enu) -> float:
    """Reflected-beam pointing error of a beam whose centroid lands at ``spot_enu``: the angle
    at the heliostat between the directions to the aim point and to the spot, mrad.

    All points in m ENU, shape (3,): ``arccos(â·ŝ)`` with â, ŝ the unit vectors from the
    heliostat to the aim point and to the spot."""
    a = np.asarray(aim_point, float) - np.asarray(heliostat_pos, float)
    b = np.asarray(spot_enu, float) - np.asarray(heliostat_pos, float)
    return float(angle_mrad(a, b))
