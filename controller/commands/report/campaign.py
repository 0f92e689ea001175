"""``heliocal report campaign --db DB --out DIR``: the morning report of a campaign."""

from __future__ import annotations

import argparse
from pathlib import Path

from controller.commands._common import add_json_option, print_json, staged_output_dir


def register(subparsers) -> None:
    p = subparsers.add_parser("campaign", help="morning report of a calibration campaign (Markdown + HTML)",
                              description="Write report.md, report.html and plots of a campaign.")
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--campaign", default=None, metavar="NAME|ID",
                   help="campaign name or id (default: latest)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.reports.campaign import write_report
    from controller.storage.db import open_existing

    with staged_output_dir(args.out) as stage, open_existing(args.db) as store:
        path = Path(args.out) / write_report(store, stage, store.find_campaign(args.campaign).id).name
    if args.json:
        print_json({"report": str(path), "html": str(path.with_suffix(".html"))})
    else:
        print(f"wrote {path} and {path.with_suffix('.html')}")
    return 0
