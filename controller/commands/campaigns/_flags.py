"""``heliocal campaign flags --db DB [--clear IDS|all [--lamp LAMP]] [--json]``: the geometries
flagged after failing on two nights (docs/nights.md, "Flagged geometries"), and clearing them.

Without ``--clear`` it lists the flags (read-only). ``--clear H01,H02`` (or ``all``) clears the
flags of those heliostats — only those under ``--lamp`` when given — so the planner may plan
those geometries again; it takes the database's campaign lock (not while a night runs). Exit 0;
2 when nothing flagged matches (nothing is written).
"""

from __future__ import annotations

import argparse

from controller.commands._id_lists import split_ids
from controller.commands.common import print_json
from controller.errors import InputError


def flags_command(args: argparse.Namespace) -> int:
    from controller.commands.field import open_store
    from controller.storage.db import open_existing
    from controller.storage.geometry_flags import clear_flags, flagged

    if args.lamp is not None and args.clear is None:
        raise InputError("--lamp: only with --clear")
    if args.clear is None:
        with open_existing(args.db) as store:
            rows = flagged(store)
        return _show(args, "flagged", rows, f"{args.db}: {len(rows)} flagged geometr"
                     f"{'y' if len(rows) == 1 else 'ies'}")
    ids = None if args.clear.strip() == "all" else split_ids(args.clear, "--clear")
    open_existing(args.db).close()  # an existing heliocal database, before taking its lock
    store = open_store(args.db)
    try:
        cleared = clear_flags(store, ids, args.lamp)
    finally:
        store.close()
    return _show(args, "cleared", cleared,
                 f"cleared {len(cleared)} flag(s); the planner may plan these geometries again:")


def _show(args, key: str, rows: list[dict], heading: str) -> int:
    """``{key: rows}`` with --json, else ``heading`` and a line per flag; exit 0."""
    if args.json:
        print_json({key: rows})
    else:
        print(heading)
        for g in rows:
            print(f"  {_line(g)}")
    return 0


def _line(g: dict) -> str:
    where = ("on every target and aim cell" if g["target"] is None
             else f"on {g['target']} (aim cell {g['cell'][0]},{g['cell'][1]})")
    return (f"{g['heliostat']} under {g['lamp']} {where}: failed on "
            f"{', '.join(g['nights'])}" + (f"; last: {g['cause']}" if g["cause"] else ""))
