"""``heliocal export``: calibration records as PAINT JSON, the tracking table and the models
for the heliostat field control (HFCS).

Contracts (scripts depend on them; docs/plant-integration.md)::

    heliocal export --db DB --format paint --out DIR [--campaign NAME|ID] [--config C]
    heliocal export tracking-table --config C --db DB --day YYYY-MM-DD [--step MINUTES]
                                   [--heliostats IDS] --out FILE.csv [--accept-field-change]
    heliocal export models --db DB --format json|csv [--heliostats IDS] [--out FILE]

The tracking table's columns are ``heliostat,time_utc,sun_azimuth_deg,sun_elevation_deg,
az_steps,el_steps,predicted_error_mrad``: every ``--step`` minutes (default 10) of the site's
mean solar day while the sun is up and the pose is within the soft limits, the steps exactly
those of ``heliocal aim --time``. Without ``--heliostats`` every heliostat with a fitted model
(those without are named on stderr); a named heliostat without one is refused (exit 2).
``models`` prints (or writes to ``--out``) each heliostat's latest model with its version.
"""

from __future__ import annotations

import argparse
import sys

from controller.commands._numbers import Number
from controller.commands.common import (
    add_field_change_option,
    add_json_option,
    check_store_field,
    output_file,
    print_json,
    staged_output_dir,
)
from controller.commands.integration._plant import heliostat_ids
from controller.errors import InputError
from controller.io.json_files import dumps_json

WHAT = ("tracking-table", "models")
FORMATS = {None: ("paint",), "tracking-table": ("csv",), "models": ("json", "csv")}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="export measurements (PAINT JSON), the tracking table or the models (HFCS)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("what", nargs="?", choices=WHAT, default=None,
                   help="tracking-table or models (default: the PAINT-style measurement records)")
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--format", default=None, choices=["paint", "json", "csv"],
                   help="paint (the records), json or csv (models)")
    p.add_argument("--out", default=None, metavar="DIR|FILE",
                   help="output directory (paint), CSV file (tracking-table), file (models; default stdout)")
    p.add_argument(
        "--campaign", default=None, metavar="NAME|ID", help="only this campaign, by name or id (default: all)"
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="plant config (tracking-table; paint: the site origin, default stored with the campaign); "
             "checked against the field the models were fitted on",
    )
    p.add_argument("--day", default=None, metavar="YYYY-MM-DD", help="the day of the tracking table")
    p.add_argument("--step", type=Number(1, 720), default=10.0, metavar="MINUTES",
                   help="minutes between two instants of the tracking table (default 10)")
    p.add_argument("--heliostats", default=None, metavar="IDS", help="comma-separated heliostat ids")
    add_field_change_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    fmt = args.format or ("csv" if args.what == "tracking-table" else None)
    if fmt not in FORMATS[args.what]:
        what = f"export {args.what}" if args.what else "export"
        raise InputError(f"{what}: --format {' or '.join(FORMATS[args.what])}")
    if args.what is None:
        return _paint(args)
    if args.campaign is not None:
        raise InputError(f"export {args.what}: --campaign goes with the PAINT export")
    if args.what == "tracking-table":
        return _tracking_table(args)
    return _models(args, fmt)


def _tracking_table(args: argparse.Namespace) -> int:
    from datetime import date

    from controller.config import load_config
    from controller.hfcs.tracking_table import write_tracking_table
    from controller.storage.db import open_existing

    if args.config is None or args.day is None or args.out is None:
        raise InputError("export tracking-table: needs --config, --day and --out")
    try:
        day = date.fromisoformat(args.day.strip())
    except ValueError:
        raise InputError(f"--day: {args.day!r} is not a date (YYYY-MM-DD)") from None
    out = output_file(args.out)
    cfg = load_config(args.config)
    ids = heliostat_ids(args.heliostats, cfg)
    with open_existing(args.db) as store:
        check_store_field(store, cfg, ids or [h.id for h in cfg.heliostats], args)  # never another field's
        models = store.latest_models(ids or [h.id for h in cfg.heliostats])
    missing = [hid for hid in (ids or [h.id for h in cfg.heliostats]) if hid not in models]
    if ids and missing:
        raise InputError(f"{args.db}: {missing[0]} has no fitted model (heliocal aim would not track it "
                         "with one); calibrate it or leave it out of --heliostats")
    if missing:
        print(f"heliocal export: no fitted model, left out: {', '.join(missing)}", file=sys.stderr)
    order = [hid for hid in (ids or [h.id for h in cfg.heliostats]) if hid in models]
    if not order:
        raise InputError(f"{args.db}: no heliostat has a fitted model (run a campaign first)")
    rows = write_tracking_table(out, cfg, {hid: models[hid] for hid in order}, day, args.step)
    if args.json:
        print_json({"ok": True, "out": str(out), "rows": rows, "heliostats": order, "day": day.isoformat()})
    else:
        print(f"wrote {rows} rows for {len(order)} heliostat(s) into {out}")
    return 0


def _models(args: argparse.Namespace, fmt: str) -> int:

    from controller.hfcs.models import model_versions, models_csv
    from controller.io.images import write_atomic
    from controller.storage.db import open_existing

    if args.config is not None or args.day is not None or args.accept_field_change:
        raise InputError("export models: --config, --day and --accept-field-change go with the tracking "
                         "table")
    out = output_file(args.out) if args.out else None
    with open_existing(args.db) as store:
        models = model_versions(store, heliostat_ids(args.heliostats))
    text = dumps_json(models) + "\n" if fmt == "json" else models_csv(models)
    if out is None:
        sys.stdout.write(text)
    else:
        write_atomic(out, lambda tmp: tmp.write_text(text, encoding="utf-8"))
        print(f"wrote {len(models)} model(s) into {out}", file=sys.stderr)
    return 0


def _paint(args: argparse.Namespace) -> int:
    from controller.storage.db import open_existing
    from controller.storage.paint.export import export_paint

    if args.out is None:
        raise InputError("export: --out DIR is required")
    if args.day is not None or args.heliostats is not None:
        raise InputError("export: --day and --heliostats go with the tracking table")
    site, cfg = None, None
    if args.config:
        from controller.config import load_config

        cfg = load_config(args.config)
        s = cfg.site
        site = (s.latitude_deg, s.longitude_deg, s.elevation_m)
    with staged_output_dir(args.out) as stage, open_existing(args.db) as store:
        if cfg is not None:  # a model is never exported against another field
            check_store_field(store, cfg, [h.id for h in cfg.heliostats], args)
        cid = None if args.campaign is None else store.find_campaign(args.campaign).id
        paths = export_paint(store, stage, site, cid)
    if args.json:
        print_json({"records": len(paths), "out": args.out})
    else:
        print(f"wrote {len(paths)} PAINT-style records into {args.out}")
    return 0
