"""``heliocal aim``: the motor steps that put a heliostat's beam on its target centre at a sun
position, with the heliostat's latest fitted model — daytime tracking, what calibration is for.

Contract (scripts depend on it)::

    heliocal aim --config C --db DB --heliostat H (--time T | --sun-az A --sun-el E) --json
    -> {"az_steps": int, "el_steps": int, "model": {...} | null, "sun": {"azimuth_deg", "elevation_deg"},
        "target": id}

``model`` is the heliostat's latest fitted tracking-error model from the database (its
parameters, 1-σ, residual and number of measurements), or null when it has none: the steps are
then those of the nominal kinematics, and the exit status is 5 (:data:`NO_MODEL`, said on
stderr too). ``--time`` is ISO 8601 with its UTC offset (or ``now``); ``--sun-az`` is clockwise
from north, degrees. Exit 2 when the pose is outside the soft limits or the sun is down, and
when the configuration's field is not the one the model was fitted on (the heliostat's position
or kinematics, a target; one line naming the heliostat or target and the key) unless
``--accept-field-change``, or when ``--config`` is left out and the database was made with
another configuration (docs/campaigns.md, "A model and its field").
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import asdict
from datetime import UTC, datetime

import numpy as np

from controller.commands._numbers import Number
from controller.commands.common import (
    add_config_option,
    add_field_change_option,
    add_json_option,
    check_store_field,
    print_json,
)
from controller.errors import InputError

NO_MODEL = 5  # exit status: no fitted model, the steps printed are the nominal kinematics


def register(subparsers) -> None:
    p = subparsers.add_parser("aim", help="motor steps for the sun on the target, with the fitted model",
                              description=__doc__.split("\n\n")[0])
    add_config_option(p)
    p.add_argument("--db", required=True, metavar="DB", help="campaign database holding the fitted models")
    p.add_argument("--heliostat", required=True, metavar="H", help="heliostat id")
    p.add_argument("--time", metavar="ISO8601", help="instant with its UTC offset, or 'now'")
    p.add_argument("--utc", action="store_true", help="read a --time without an offset as UTC")
    p.add_argument("--sun-az", type=Number(-360, 360), metavar="DEG",
                   help="sun azimuth, clockwise from north, degrees")
    p.add_argument("--sun-el", type=Number(-90, 90), metavar="DEG", help="sun elevation, degrees")
    add_field_change_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.calibration.cycle.pointing import steps_to_aim
    from controller.commands.devices.sun import parse_time
    from controller.config import load_config
    from controller.geometry.kinematics import HeliostatKinematics
    from controller.geometry.vectors import azel_to_vector
    from controller.storage.db import open_existing

    by_angles = args.sun_az is not None or args.sun_el is not None
    if by_angles == (args.time is not None) or (by_angles and (args.sun_az is None or args.sun_el is None)):
        raise InputError("give either --time, or both --sun-az and --sun-el")
    cfg = load_config(args.config)
    h = cfg.heliostat(args.heliostat)
    if by_angles:
        az, el = args.sun_az, args.sun_el
        if not (math.isfinite(az) and math.isfinite(el) and 0 < el <= 90):
            raise InputError(f"--sun-az/--sun-el: need finite angles with the sun up (0 < el <= 90), got "
                             f"{az}, {el}")
    else:
        from controller.geometry.sun import solar_position

        s = cfg.site
        pos = solar_position(parse_time(args.time, args.utc), s.latitude_deg, s.longitude_deg, s.elevation_m,
                             s.pressure_mbar, s.temperature_c, s.delta_t_s)
        az, el = float(pos.azimuth_deg), float(pos.elevation_deg)
        if el <= 0:
            raise InputError(f"--time {args.time}: the sun is down at the site (elevation {el:.2f}°)")
    with open_existing(args.db) as store:
        check_store_field(store, cfg, [h.id], args)  # never a model on another field
        model = store.latest_model(h.id)
    target = cfg.target()
    a, e = steps_to_aim(HeliostatKinematics.from_config(h), model, azel_to_vector(az % 360.0, el),
                        np.asarray(target.center_enu_m, float))
    out = {"az_steps": int(a), "el_steps": int(e), "model": None if model is None else asdict(model),
           "sun": {"azimuth_deg": az % 360.0, "elevation_deg": el}, "target": target.id,
           "heliostat": h.id, "time": None if args.time is None else datetime.now(UTC).isoformat()
           if args.time.strip().lower() == "now" else args.time}
    if args.json:
        print_json(out)
    else:
        source = "fitted model" if model else "nominal kinematics (no fitted model yet)"
        print(f"{h.id}: az {a} el {e} steps for the sun at azimuth {az % 360.0:.3f}°, elevation {el:.3f}° "
              f"on {target.id} ({source})")
    if model is None:
        print(f"heliocal aim: {h.id} has no fitted model in {args.db}: nominal kinematics (exit {NO_MODEL})",
              file=sys.stderr)
        return NO_MODEL
    return 0
