"""Apparent solar position from the NREL Solar Position Algorithm (SPA), through pvlib.

Conventions: azimuth clockwise from north in [0, 360) degrees, elevation up from the horizon;
both *apparent* (topocentric, corrected for atmospheric refraction with the given pressure and
temperature). Times are timezone-aware datetimes; a naive datetime is taken as UTC.

pvlib is imported inside :func:`solar_position` because importing it takes about 1.6 s, which
commands that never need the sun should not pay.

References
----------
.. [1] I. Reda and A. Andreas, "Solar position algorithm for solar radiation applications",
   Solar Energy 76(5), 577-589, 2004; NREL/TP-560-34302 (revised 2008). Stated uncertainty
   ±0.0003°; worked example in Table A5.1 (2003-10-17 12:30:30 UTC-7, Golden, CO).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np


@dataclass(frozen=True)
class SolarPosition:
    """Apparent solar position, degrees. Floats for one time, arrays of shape (n,) for n times."""

    zenith_deg: float | np.ndarray
    azimuth_deg: float | np.ndarray
    elevation_deg: float | np.ndarray

    def to_dict(self) -> dict:
        return {"zenith_deg": self.zenith_deg, "azimuth_deg": self.azimuth_deg,
                "elevation_deg": self.elevation_deg}


def as_utc(time: datetime) -> datetime:
    """Return ``time`` as an aware UTC datetime; a naive datetime is taken as UTC already."""
    if time.tzinfo is None or time.tzinfo.utcoffset(time) is None:
        return time.replace(tzinfo=UTC)
    return time.astimezone(UTC)


def solar_position(time: datetime | Sequence[datetime], latitude_deg: float, longitude_deg: float,
                   elevation_m: float = 0.0, pressure_mbar: float = 1013.25, temperature_c: float = 12.0,
                   delta_t_s: float | None = None) -> SolarPosition:
    """Apparent topocentric solar position by NREL SPA [1]_.

    Parameters
    ----------
    time : datetime or sequence of datetime
        Instant(s); timezone-aware, or naive meaning UTC.
    latitude_deg, longitude_deg : float
        Observer's geodetic latitude (north positive) and longitude (east positive), degrees.
    elevation_m : float
        Observer's height above mean sea level, m.
    pressure_mbar : float
        Local annual average air pressure, mbar (hPa); used for the refraction correction.
    temperature_c : float
        Local annual average air temperature, °C; used for the refraction correction.
    delta_t_s : float or None
        ΔT = TT − UT1 in seconds; None estimates it from the date (pvlib's polynomial fit).

    Returns
    -------
    SolarPosition
        ``zenith_deg`` (apparent, refraction-corrected), ``azimuth_deg`` clockwise from north in
        [0, 360) and ``elevation_deg`` = 90 − zenith_deg. Floats for a single datetime, arrays of
        shape (n,) for a sequence.

    References
    ----------
    .. [1] Reda & Andreas (2004), Solar Energy 76(5) 577-589, Eqs. (3)-(47); the apparent
       topocentric zenith is Eq. (44), the topocentric azimuth Eq. (47).
    """
    import pandas as pd
    from pvlib.solarposition import spa_python

    single = isinstance(time, datetime)
    times = [time] if single else list(time)
    index = pd.DatetimeIndex([as_utc(t) for t in times])
    result = spa_python(index, latitude_deg, longitude_deg, altitude=elevation_m,
                        pressure=pressure_mbar * 100.0, temperature=temperature_c, delta_t=delta_t_s)
    zenith = result["apparent_zenith"].to_numpy(dtype=float)
    azimuth = result["azimuth"].to_numpy(dtype=float) % 360.0
    elevation = 90.0 - zenith
    if single:
        return SolarPosition(float(zenith[0]), float(azimuth[0]), float(elevation[0]))
    return SolarPosition(zenith, azimuth, elevation)
