"""``heliocal import paint``: a PAINT folder's calibration records into the field's store.

Contract (scripts depend on it)::

    heliocal import paint DIR --db DB [--config C] [--timestamps FILE] [--json]
    -> {"db", "config", "config_sha256", "config_written", "campaign", "imported",
        "already_imported", "heliostats": {H: {"records", "imported", "already_imported", "no_time",
        "helios_only", "outside_soft_limits", "outside_triangle", "nominal_miss_mrad", "note"}},
        "refused": {H: why}, "seconds"}

DIR in PAINT's layout: ``<H>/<H>_properties.json``, ``<H>/calibration/<id>_calibration_properties.json``,
``timestamps.json`` (or ``--timestamps``), ``tower-measurements.json``. Each record with a time
becomes a measurement with its UTC time, the sun's direction and its focal spot (UTIS, else
HeliOS). Without ``--config`` the field's configuration is written beside DB
(``<DB stem>.config.yaml``: link ``none``, no camera driver) for the later commands. A re-import
adds only new records. Bad files: exit 2 naming the file and key, nothing written
(docs/import.md).
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    from controller.commands.common import add_json_option

    p = subparsers.add_parser("paint", help="a PAINT folder's calibration records into a database",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("dir", metavar="DIR", help="folder in PAINT's layout (<H>/<H>_properties.json, ...)")
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite; created if missing)")
    p.add_argument("--config", default=None, metavar="C",
                   help="the field's configuration (default: written beside DB from the folder)")
    p.add_argument("--timestamps", default=None, metavar="FILE",
                   help="record times, {\"<H>_<id>\": UTC time} (default: DIR/timestamps.json)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands.common import print_json
    from controller.storage.paint.import_records import import_paint

    r = import_paint(args.dir, args.db, config=args.config, timestamps=args.timestamps)
    if args.json:
        print_json(r.to_json())
        return 0
    print(f"imported {r.imported} new record(s) of {len(r.heliostats) - len(r.refused)} heliostat(s) into "
          f"{r.db}" + (f" as campaign {r.campaign}" if r.campaign else "")
          + f" ({r.already_imported} imported before); field configuration {r.config} "
          + ("(written)" if r.config_written else "(unchanged)"))
    for hid, h in r.heliostats.items():
        parts = [f"{h.imported} new of {h.records}"]
        if h.no_time:
            parts.append(f"{len(h.no_time)} without a time, not imported ({', '.join(h.no_time)})")
        if h.helios_only:
            parts.append(f"{len(h.helios_only)} with a HeliOS spot only, used ({', '.join(h.helios_only)})")
        if h.outside_soft_limits:
            parts.append(f"{h.outside_soft_limits} at motor positions outside the soft limits")
        if h.outside_triangle:
            parts.append(f"{h.outside_triangle} where the configured stroke leaves the actuator triangle")
        if h.nominal_miss_mrad is not None:
            parts.append(f"nominal kinematics miss by {h.nominal_miss_mrad} mrad (median, normal)")
        if hid in r.refused:
            parts = [f"refused, nothing imported: {r.refused[hid]}"]
        elif h.note:
            parts.append(h.note)
        print(f"  {hid}: " + "; ".join(parts))
    return 0
