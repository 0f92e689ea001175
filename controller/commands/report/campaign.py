"""``heliocal report campaign --db DB --out DIR``: the morning report of the latest whole night
(its calibration campaign for night 0, its passes for a planned night), or of the night or
campaign named."""

from __future__ import annotations

import argparse
from pathlib import Path

from controller.commands.common import (
    add_field_change_option,
    add_json_option,
    print_json,
    staged_output_dir,
)
from controller.errors import InputError
from controller.io.text_numbers import is_ascii_index


def register(subparsers) -> None:
    p = subparsers.add_parser("campaign", help="morning report of a night or campaign (Markdown + HTML)",
                              description="Write report.md, report.html and plots of the latest whole night "
                                          "(finished or partial), or of the night or campaign named.")
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--campaign", default=None, metavar="NAME|ID", help="campaign name or id")
    which.add_argument("--night", default=None, metavar="INDEX|NAME",
                       help="night index (0: the calibration night) or name (default: the latest "
                            "whole night)")
    add_field_change_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.reports.campaign import write_report
    from controller.reports.night import write_night_report
    from controller.storage.db import open_existing

    with staged_output_dir(args.out) as stage, open_existing(args.db) as store:
        night = None if args.campaign is not None else _night(store, args.night)
        if night is not None and night.kind == "planned":
            written = write_night_report(store, stage, night)
        else:
            camp = store.find_campaign(night.name if night is not None else args.campaign)
            written = write_report(store, stage, camp.id, accept_field_change=args.accept_field_change)
        path = Path(args.out) / written.name
    if args.json:
        print_json({"report": str(path), "html": str(path.with_suffix(".html")),
                    "night": None if night is None else night.index})
    else:
        print(f"wrote {path} and {path.with_suffix('.html')}")
    return 0


def _night(store, ref: str | None):
    """The night ``ref`` names (index or name), or the latest whole one (finished or partial);
    None when the database records no night (campaigns from before nights: the latest campaign)."""
    from controller.storage.nights import NightBook

    nights = NightBook(store).nights()
    if ref is None:
        whole = [n for n in nights if n.status in ("finished", "partial")]
        return whole[-1] if whole else None
    for n in nights:
        if n.name == ref or (is_ascii_index(ref) and n.index == int(ref)):
            return n
    raise InputError(f"{store.path}: no night {ref!r} (see heliocal campaign list)")
