"""``heliocal model predict``: where a record's beam lands, predicted with a fitted model.

Contract (scripts depend on it)::

    heliocal model predict MODEL.json --record RECORD.json --towers TOWERS.json --json
    -> {"focal_spot_wgs84": [lat, lon, alt], "focal_spot_enu_m": [e, n, u], "target": NAME, ...}

The reflected central ray, from the record's motor steps and sun position through the model,
meets the record's target plane there. The record's own focal spot is not read.
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser("predict", help="predict a record's focal spot with a fitted model",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("model", metavar="MODEL.json", help="model written by 'heliocal model fit'")
    p.add_argument("--record", required=True, metavar="RECORD.json",
                   help="PAINT calibration-properties record")
    p.add_argument("--towers", required=True, metavar="TOWERS.json", help="tower-measurements file (targets)")
    p.add_argument("--json", action="store_true", help="print the prediction as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands._common import print_json
    from controller.geometry.frames import enu_to_wgs84
    from controller.geometry.paint_io import read_record, read_towers
    from controller.geometry.tracking_model import model_normal, model_spot
    from controller.storage.model_file import read_model

    mf = read_model(args.model)
    towers = read_towers(args.towers)
    rec = read_record(args.record, towers, with_spot=False)
    kin = mf.kinematics()
    s = rec.sample
    spot = model_spot(kin, mf.model, s.az_steps, s.el_steps, s.source_dir, rec.target.center_enu,
                      rec.target.normal)
    wgs = enu_to_wgs84(list(spot), *towers.origin_wgs84)
    out = {"focal_spot_wgs84": [float(v) for v in wgs], "focal_spot_enu_m": [float(v) for v in spot],
           "target": rec.target.name, "heliostat": mf.heliostat_id,
           "normal_enu": [float(v) for v in model_normal(kin, mf.model, s.az_steps, s.el_steps)],
           "motor_position": {"axis_1_motor_position": s.el_steps, "axis_2_motor_position": s.az_steps},
           "sun": {"azimuth_deg": rec.sun_azimuth_deg, "elevation_deg": rec.sun_elevation_deg}}
    if args.json:
        print_json(out)
    else:
        e, n, u = spot
        print(f"{mf.heliostat_id} on {rec.target.name}: focal spot E {e:.3f} N {n:.3f} U {u:.3f} m "
              f"(lat {wgs[0]:.8f}, lon {wgs[1]:.8f}, alt {wgs[2]:.3f} m)")
    return 0
