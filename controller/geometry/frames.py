"""Geodetic (WGS84) and local East-North-Up (ENU) frames; the PAINT azimuth convention.

ENU: x = east, y = north, z = up, metres, tangent to the WGS84 ellipsoid at an origin. The
conversion is exact (geodetic -> ECEF -> rotation into the origin's tangent frame), not the
flat-earth approximation, so it holds to well under a millimetre over a heliostat field.

References
----------
.. [1] NIMA TR8350.2, "Department of Defense World Geodetic System 1984", 3rd ed., 2000:
   a = 6378137 m, 1/f = 298.257223563; geodetic to ECEF, Eq. (4-14).
.. [2] J. Farrell and M. Barth, "The Global Positioning System and Inertial Navigation",
   McGraw-Hill 1999, Sec. 2.3: ECEF to local ENU rotation.
.. [3] B. R. Bowring, "Transformation from spatial to geographical coordinates",
   Survey Review 23(181), 323-327, 1976: closed-form ECEF to geodetic.
"""

from __future__ import annotations

import numpy as np

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
WGS84_B = WGS84_A * (1.0 - WGS84_F)


def wgs84_to_ecef(lat_deg, lon_deg, alt_m) -> np.ndarray:
    """Earth-centred Earth-fixed coordinates, m, of WGS84 geodetic points. Returns (..., 3).

    Heights are ellipsoidal; PAINT/ARTIST altitudes are used as given (over ~100 m the
    geoid-ellipsoid difference is a constant that cancels in ENU differences).

    References: [1]_ Eq. (4-14).
    """
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    alt = np.asarray(alt_m, dtype=float)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + alt) * np.cos(lat) * np.cos(lon),
                     (n + alt) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - WGS84_E2) + alt) * np.sin(lat)], axis=-1)


def _ecef_to_enu_matrix(lat_deg: float, lon_deg: float) -> np.ndarray:
    """3x3 rotation whose rows are the E, N, U unit vectors at the origin, in ECEF. [2]_"""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, co, 0.0],
                     [-sl * co, -sl * so, cl],
                     [cl * co, cl * so, sl]])


def wgs84_to_enu(lat_deg, lon_deg, alt_m, origin_lat_deg: float, origin_lon_deg: float,
                 origin_alt_m: float) -> np.ndarray:
    """Local ENU coordinates, m, of WGS84 points about a WGS84 origin.

    Parameters
    ----------
    lat_deg, lon_deg : float or array
        Geodetic latitude (north +) and longitude (east +), degrees.
    alt_m : float or array
        Height, m.
    origin_lat_deg, origin_lon_deg, origin_alt_m : float
        The ENU origin.

    Returns
    -------
    ndarray, shape (..., 3)
        (east, north, up) in metres.

    References: [1]_ Eq. (4-14), [2]_ Sec. 2.3.
    """
    d = wgs84_to_ecef(lat_deg, lon_deg, alt_m) - wgs84_to_ecef(origin_lat_deg, origin_lon_deg, origin_alt_m)
    return d @ _ecef_to_enu_matrix(origin_lat_deg, origin_lon_deg).T


def enu_to_wgs84(enu_m, origin_lat_deg: float, origin_lon_deg: float,
                 origin_alt_m: float) -> np.ndarray:
    """Inverse of :func:`wgs84_to_enu`: (lat_deg, lon_deg, alt_m) of ENU points. Shape (..., 3).

    Uses Bowring's closed form [3]_ with one refinement, accurate to < 1 mm near the surface.
    """
    rot = _ecef_to_enu_matrix(origin_lat_deg, origin_lon_deg)
    xyz = np.asarray(enu_m, dtype=float) @ rot + wgs84_to_ecef(origin_lat_deg, origin_lon_deg, origin_alt_m)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    ep2 = (WGS84_A**2 - WGS84_B**2) / WGS84_B**2
    lat = np.arctan2(z * WGS84_A, p * WGS84_B)  # parametric-latitude start
    for _ in range(2):
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
        lat = np.arctan2(z + ep2 * WGS84_B * np.sin(beta) ** 3, p - WGS84_E2 * WGS84_A * np.cos(beta) ** 3)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    alt = p / np.cos(lat) - n
    return np.stack([np.degrees(lat), np.degrees(np.arctan2(y, x)), alt], axis=-1)


def paint_azimuth_to_north(sun_azimuth_deg):
    """Convert a PAINT record's ``sun_azimuth`` (from south, positive towards east) to ours.

    Ours is clockwise from north in [0, 360): A = (180 − A_paint) mod 360. PAINT −85.60°
    (85.6° west of south) becomes 265.60°.
    """
    return (180.0 - np.asarray(sun_azimuth_deg, dtype=float)) % 360.0
