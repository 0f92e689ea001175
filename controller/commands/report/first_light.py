"""``heliocal report first-light --db DB --out DIR``: the report of first light on a new field
(docs/commissioning.md, "First light on a new field") of a campaign: per heliostat whether its
beam was found, the beam search's looks and time, where its beam landed against its model's aim."""

from __future__ import annotations

import argparse
from pathlib import Path

from controller.commands.common import add_json_option, print_json, staged_output_dir


def register(subparsers) -> None:
    p = subparsers.add_parser("first-light", description=__doc__.splitlines()[0],
                              help="first light on a new field: beams found, search looks and time")
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--campaign", default=None, metavar="NAME|ID",
                   help="campaign name or id (default: the latest)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.reports.first_light import first_light, write_first_light
    from controller.storage.db import open_existing

    with open_existing(args.db) as store:
        cid = store.find_campaign(args.campaign).id
    report = first_light(args.db, cid)
    with staged_output_dir(args.out) as stage:
        written = write_first_light(report, stage)
    path = Path(args.out) / written.name
    if args.json:
        print_json({"report": str(path), **report})
    else:
        t = report["totals"]
        print(f"{t['found']} of {t['heliostats']} beams found, {t['calibrated']} calibrated, "
              f"{t['search_looks']} search looks, {t['search_s']:.0f} s searching; wrote {path}")
    return 0
