"""``heliocal sun``: apparent solar position (NREL SPA) for a time and place.

Contract (scripts depend on it): ``--json`` prints ONE object
``{"zenith_deg": z, "azimuth_deg": a, "elevation_deg": e}``; azimuth clockwise from north in
[0, 360); elevation = 90 − zenith, both apparent (refraction-corrected). ``--time`` is ISO 8601
with its UTC offset (``Z`` or ``+02:00``), or ``now`` (the default); a time without an offset is
refused unless ``--utc`` says it is UTC, since a local clock time read as UTC puts the sun
hours off. Without ``--lat``/``--lon`` the site of ``--config`` is used, with its elevation,
pressure, temperature and ΔT unless given. Bad input exits 2.
"""

from __future__ import annotations

import argparse
import math
from datetime import UTC, datetime

from controller.commands.common import DEFAULT_CONFIG, add_config_option, add_json_option, print_json
from controller.errors import InputError

# option -> (lowest, highest) accepted value
_RANGES = {"lat": (-90.0, 90.0), "lon": (-180.0, 180.0), "elevation": (-500.0, 9000.0),
           "pressure": (1e-3, 1200.0), "temperature": (-90.0, 70.0), "delta_t": (-10000.0, 10000.0)}


def register(subparsers) -> None:
    p = subparsers.add_parser("sun", help="apparent solar position (NREL SPA) for a time and place",
                              description=__doc__.splitlines()[0])
    p.add_argument("--time", metavar="ISO8601", help="instant with its UTC offset, e.g. "
                   "2003-10-17T12:30:30-07:00 or 2024-06-21T12:00:00Z, or 'now' (default: now)")
    p.add_argument("--utc", action="store_true", help="read a --time without an offset as UTC")
    p.add_argument("--lat", metavar="DEG", help="latitude, degrees north (default: site of --config)")
    p.add_argument("--lon", metavar="DEG", help="longitude, degrees east (default: site of --config)")
    p.add_argument("--elevation", metavar="M", help="height above sea level, m (default 0)")
    p.add_argument("--pressure", metavar="MBAR", help="air pressure, mbar (default 1013.25)")
    p.add_argument("--temperature", metavar="C", help="air temperature, °C (default 12)")
    p.add_argument("--delta-t", dest="delta_t", metavar="S", help="ΔT = TT − UT1, s (default: estimated)")
    add_config_option(p, resolve=False)  # a plant is read only without --lat/--lon
    add_json_option(p)
    p.set_defaults(func=run)


def parse_time(text: str, naive_is_utc: bool = False) -> datetime:
    """ISO 8601 text (or ``now``) -> aware datetime; a time without an offset only with
    ``naive_is_utc``. InputError naming the value otherwise."""
    if text.strip().lower() == "now":
        return datetime.now(UTC)
    try:
        t = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"--time: {text!r} is not an ISO 8601 time "
                         "(e.g. 2003-10-17T12:30:30-07:00)") from None
    if t.year > 6000:  # SPA's stated validity ends at year 6000
        raise InputError(f"--time: {text!r} is outside the SPA's validity (-2000..6000)")
    if t.tzinfo is None:
        if not naive_is_utc:
            raise InputError(f"--time: {text!r} has no UTC offset; add one (e.g. {text.strip()}Z or "
                             f"{text.strip()}+02:00) or pass --utc")
        return t.replace(tzinfo=UTC)
    return t


def _number(args: argparse.Namespace, name: str) -> float | None:
    text = getattr(args, name)
    if text is None:
        return None
    option = "--" + name.replace("_", "-")
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{option}: {text!r} is not a number") from None
    lo, hi = _RANGES[name]
    if not math.isfinite(value) or not lo <= value <= hi:
        raise InputError(f"{option}: {text} is outside [{lo:g}, {hi:g}]")
    return value


def _deg(value: float, positive: str, negative: str) -> str:
    """105.1786°W rather than -105.1786°E."""
    return f"{abs(value):.6f}°{positive if value >= 0 else negative}"


def run(args: argparse.Namespace) -> int:
    values = {name: _number(args, name) for name in _RANGES}
    if (values["lat"] is None) != (values["lon"] is None):
        raise InputError("--lat and --lon must be given together (or neither, to use the config's site)")
    when = parse_time(args.time, args.utc) if args.time is not None else datetime.now(UTC)
    site = {"elevation": 0.0, "pressure": 1013.25, "temperature": 12.0, "delta_t": None}
    if values["lat"] is None:
        from controller.config import load_config

        s = load_config(args.config or DEFAULT_CONFIG).site
        values["lat"], values["lon"] = s.latitude_deg, s.longitude_deg
        site = {"elevation": s.elevation_m, "pressure": s.pressure_mbar, "temperature": s.temperature_c,
                "delta_t": s.delta_t_s}
    for name, default in site.items():
        if values[name] is None:
            values[name] = default
    from controller.geometry.sun import solar_position

    pos = solar_position(when, values["lat"], values["lon"], values["elevation"], values["pressure"],
                         values["temperature"], values["delta_t"])
    if args.json:
        print_json(pos.to_dict())
    else:
        print(f"{when.isoformat()} at {_deg(values['lat'], 'N', 'S')} {_deg(values['lon'], 'E', 'W')}: "
              f"azimuth {pos.azimuth_deg:.5f}° (clockwise from north), elevation {pos.elevation_deg:.5f}°, "
              f"zenith {pos.zenith_deg:.5f}° (apparent)")
    return 0
