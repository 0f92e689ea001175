"""``heliocal model predict``: where records' beams land, predicted with a fitted model.

Contract (scripts depend on it)::

    heliocal model predict MODEL.json --record RECORD.json [RECORD.json ...] --towers TOWERS.json
                           [--timestamps TS.json] --json
    -> one JSON object per record, in order, one per line:
       {"focal_spot_wgs84": [lat, lon, alt], "focal_spot_enu_m": [e, n, u], "target": NAME, ...}

The reflected central ray, from the record's motor steps and sun position through the model,
meets the record's target plane there. The record's own focal spot is not read. With
``--timestamps`` each object also gives the record's time, the model's age then and the σ its
references have drifted by since (the model's random walk); a record within the span the model
was fitted over is predicted with the references the fit found at its time. A record whose motor steps the
model cannot evaluate (an actuator outside its triangle) gives an object with ``error`` and
the command ends with exit 2 after the others.
"""

from __future__ import annotations

import argparse
import math
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser("predict", help="predict records' focal spots with a fitted model",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("model", metavar="MODEL.json", help="model written by 'heliocal model fit'")
    p.add_argument("--record", required=True, nargs="+", metavar="RECORD.json",
                   help="PAINT calibration-properties record(s)")
    p.add_argument("--towers", required=True, metavar="TOWERS.json", help="tower-measurements file (targets)")
    p.add_argument("--timestamps", metavar="TS.json", default=None,
                   help="PAINT timestamps file: each record's time, the model's age and drift then")
    p.add_argument("--json", action="store_true", help="print one JSON object per record")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands.common import print_json
    from controller.geometry.paint_io import read_record, read_timestamps, read_towers, record_times
    from controller.storage.model_file import read_model

    mf = read_model(args.model)
    towers = read_towers(args.towers)
    records = [read_record(r, towers, with_spot=False) for r in args.record]  # every file checked first
    times = None
    if args.timestamps:
        times, notes = record_times(mf.heliostat_id, args.record, read_timestamps(args.timestamps))
        for note in notes:
            print(f"heliocal: {note}", file=sys.stderr)
    failed = 0
    for k, rec in enumerate(records):
        out = _predict(mf, towers, rec, None if times is None else times[k])
        if times is not None:
            out.update(_age(mf, times[k]))
        failed += "error" in out
        if args.json:
            print_json(out)
        elif "error" in out:
            print(f"{mf.heliostat_id} {rec.source}: {out['error']}")
        else:
            e, n, u = out["focal_spot_enu_m"]
            lat, lon, alt = out["focal_spot_wgs84"]
            print(f"{mf.heliostat_id} on {rec.target.name}: focal spot E {e:.3f} N {n:.3f} U {u:.3f} m "
                  f"(lat {lat:.8f}, lon {lon:.8f}, alt {alt:.3f} m)")
    if failed:
        print(f"heliocal model predict: {failed} of {len(records)} record(s) could not be predicted",
              file=sys.stderr)
        return 2
    return 0


def _predict(mf, towers, rec, days: float | None) -> dict:
    """The prediction object of one record at time ``days`` (module docstring), or one with
    ``error``."""
    from controller.geometry.frames import enu_to_wgs84
    from controller.geometry.model.tracking import model_normal, model_spot

    kin, s, model = mf.kinematics(), rec.sample, mf.model_at(days)
    out = {"record": rec.source, "target": rec.target.name, "heliostat": mf.heliostat_id,
           "motor_position": {"axis_1_motor_position": s.el_steps, "axis_2_motor_position": s.az_steps},
           "sun": {"azimuth_deg": rec.sun_azimuth_deg, "elevation_deg": rec.sun_elevation_deg}}
    try:
        spot = model_spot(kin, model, s.az_steps, s.el_steps, s.source_dir, rec.target.center_enu,
                          rec.target.normal)
        normal = model_normal(kin, model, s.az_steps, s.el_steps)
    except ValueError as exc:  # the actuator law has no angle at these steps
        return {**out, "focal_spot_wgs84": None, "focal_spot_enu_m": None,
                "error": f"the model cannot evaluate these motor steps: {exc}"}
    wgs = enu_to_wgs84(list(spot), *towers.origin_wgs84)
    return {"focal_spot_wgs84": [float(v) for v in wgs], "focal_spot_enu_m": [float(v) for v in spot],
            **out, "normal_enu": [float(v) for v in normal]}


def _age(mf, days: float | None) -> dict:
    """The record's time, the model's age then (days after its newest session) and the σ of
    its references' drift since (mrad, the model's random walk); None where unknown."""
    from datetime import UTC, datetime

    when = None if days is None else datetime.fromtimestamp(days * 86400.0, UTC).isoformat(timespec="seconds")
    if days is None or mf.reference_days is None or mf.walk is None:
        return {"time_utc": when, "model_age_days": None, "drift_sigma_mrad": None}
    age = days - mf.reference_days
    sd = math.hypot(mf.walk.sigma_per_sqrt_day * math.sqrt(max(age, 0.0)), mf.walk.jump if age > 0 else 0.0)
    return {"time_utc": when, "model_age_days": age, "drift_sigma_mrad": 1e3 * sd}
