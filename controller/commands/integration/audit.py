"""``heliocal audit``: who did what, when (docs/plant-integration.md, "Audit").

Contract (scripts depend on it)::

    heliocal audit [--since ISO] [--db DB] [--json]
    -> [{"time", "user", "action", "target", "detail"}, ...]

Every action that moved hardware, switched a lamp, started or stopped a night or a campaign,
acknowledged or shelved an alarm, changed a model or an account, oldest first; ``--since`` is
ISO 8601 with its offset (a date alone: from its UTC midnight). Exit 0, 2 bad input.
"""

from __future__ import annotations

from controller.commands.common import add_json_option, print_json
from controller.commands.integration._plant import add_db_option, database


def register(subparsers) -> None:
    p = subparsers.add_parser("audit", help="the audit trail: who did what, when",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--since", metavar="ISO", help="from this time on (ISO 8601 with its offset, or a date)")
    add_db_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.storage.audit import audit_entries, parse_since
    from controller.storage.db import CampaignStore

    since = parse_since(args.since)
    with CampaignStore(database(args)) as store:
        rows = audit_entries(store, since)
    out = [{k: r[k] for k in ("time", "user", "action", "target", "detail")} for r in rows]
    if args.json:
        print_json(out)
        return 0
    for r in out:
        print(f"{r['time']}  {r['user']:<16} {r['action']:<20} {r['target']:<16} {r['detail']}")
    if not out:
        print("no audited action" + (f" since {args.since}" if args.since else ""))
    return 0
