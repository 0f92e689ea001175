"""When several beams may share a target (``calibration.beams_per_target`` K > 1): lamps at night.

A target is protected from concentrated *sunlight*: under the sun, one beam per target,
always. A lamp's reflected beam at night is weak (a lamp of ~1 m at ~100 m delivers a few W/m²
per heliostat, not the sun's ~1 kW/m² times the mirror's concentration), so K beams of a lamp
on one target at once do not endanger it. The mode is therefore refused

* in the configuration when the calibration light source or any planned lamp is the sun
  (:class:`controller.config.PlantConfig`, key ``calibration.beams_per_target``), and
* for any campaign or pass whose light source is the sun, or which starts in daylight: the sun
  above :data:`DAYLIGHT_ELEVATION_DEG` at the site, at the plant's time (:func:`beams_allowed`).

A planned night with K > 1 therefore ends at sunrise (:func:`night_over`): no further lamp is
lit and no further pass starts, the passes running go on to their end (they started at night),
and the night ends ``partial``; its passes not started are planned again by the next night.

Person zones, path safety and the lamp change are unchanged by it.
"""

from __future__ import annotations

from datetime import datetime

from controller.config import PlantConfig
from controller.errors import InputError
from controller.geometry.sun import solar_position

# Sunrise / sunset: the sun's upper limb on the horizon with standard refraction.
DAYLIGHT_ELEVATION_DEG = -0.833


def sun_elevation_deg(cfg: PlantConfig, utc: str) -> float:
    """The sun's apparent elevation (degrees) at the site at ``utc`` (ISO 8601)."""
    s = cfg.site
    t = datetime.fromisoformat(utc.replace("Z", "+00:00"))
    return float(solar_position(t, s.latitude_deg, s.longitude_deg, s.elevation_m, s.pressure_mbar,
                                s.temperature_c, s.delta_t_s).elevation_deg)


def beams_allowed(cfg: PlantConfig, source_id: str, utc: str) -> int:
    """The beams a campaign under light source ``source_id`` starting at ``utc`` may put on
    its target: ``calibration.beams_per_target`` for a lamp at night; 1 when K is 1. A K > 1
    with the sun as the source or in daylight is refused (InputError naming the key)."""
    k = cfg.calibration.beams_per_target
    if k == 1:
        return 1
    source = cfg.light_source(source_id)
    if source.kind != "lamp":
        raise InputError(f"calibration.beams_per_target: {k} beams on one target need a lamp; "
                         f"light source {source_id!r} is the sun (one beam per target)")
    elev = sun_elevation_deg(cfg, utc)
    if elev > DAYLIGHT_ELEVATION_DEG:
        raise InputError(f"calibration.beams_per_target: {k} beams on one target are for lamps at night; "
                         f"the sun is up ({elev:.1f}° at {utc}): one beam per target in daylight")
    return k


def night_over(cfg: PlantConfig, utc: str) -> str | None:
    """Why a planned night with K > 1 beams per target may start no further pass at ``utc``
    (ISO 8601): the sun is up (:func:`beams_allowed` would refuse it); None while it is night,
    and always with one beam per target."""
    if cfg.calibration.beams_per_target == 1:
        return None
    elev = sun_elevation_deg(cfg, utc)
    if elev <= DAYLIGHT_ELEVATION_DEG:
        return None
    return (f"daylight: the sun is up ({elev:.1f}° at {utc}), {cfg.calibration.beams_per_target} beams "
            "per target are for the night")
