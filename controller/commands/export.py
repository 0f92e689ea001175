"""``heliocal export --db DB --format paint --out DIR``: calibration records as PAINT JSON."""

from __future__ import annotations

import argparse

from controller.commands._common import (
    add_field_change_option,
    add_json_option,
    check_store_field,
    print_json,
    staged_output_dir,
)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export",
        help="export calibration measurements (PAINT-style JSON)",
        description="Write one PAINT-style calibration-properties JSON per measurement.",
    )
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--format", required=True, choices=["paint"], help="record format")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--campaign", default=None, metavar="NAME|ID", help="only this campaign, by name or id (default: all)"
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="plant config giving the site origin (default: stored with the campaign); checked against the "
             "field the models were fitted on",
    )
    add_field_change_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.storage.db import open_existing
    from controller.storage.paint import export_paint

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
