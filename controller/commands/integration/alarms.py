"""``heliocal alarms``: the plant's alarm list (docs/plant-integration.md, "Alarms").

Contract (scripts depend on it)::

    heliocal alarms [list | ack ID | shelve ID --for DURATION] [--comment TEXT] [--all] [--db DB] [--json]

``list`` (the default) prints the alarms not in the normal state, most urgent first (``--all``:
every alarm); ``ack ID`` acknowledges one, ``shelve ID --for 2h`` shelves it (at most 7 days),
``unshelve ID`` annunciates it again — each recorded with who (the operating system's user) in
the history and the audit trail. JSON: a list of alarms ``{"id", "condition", "source",
"priority", "severity", "state", "active", "acknowledged", "message", "raised_utc",
"cleared_utc", "count", "acknowledged_by", "acknowledged_utc", "ack_comment",
"shelved_until_utc", "shelved_by"}``; ``ack``/``shelve``/``unshelve`` print the one alarm.
Exit 0, 2 bad input (no such alarm, nothing to acknowledge, a bad duration).
"""

from __future__ import annotations

from controller.commands.common import add_json_option, print_json
from controller.commands.integration._plant import add_db_option, cli_user, database
from controller.errors import InputError
from controller.io.text_numbers import is_ascii_index

ACTIONS = ("list", "ack", "shelve", "unshelve")


def register(subparsers) -> None:
    p = subparsers.add_parser("alarms", help="the alarm list: list, acknowledge, shelve",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("action", nargs="?", default="list", choices=ACTIONS,
                   help="list (default), ack, shelve, unshelve")
    p.add_argument("id", nargs="?", metavar="ID", help="the alarm's id (ack, shelve, unshelve)")
    p.add_argument("--for", dest="duration", metavar="DURATION", help="how long to shelve: 30m, 2h, 1d")
    p.add_argument("--comment", default="", metavar="TEXT", help="why (recorded with the acknowledgement)")
    p.add_argument("--all", action="store_true", help="list every alarm, those back to normal too")
    add_db_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.alarms.states import now_utc, parse_duration
    from controller.storage.alarms import AlarmBook
    from controller.storage.db import CampaignStore

    if args.action == "list" and args.id is not None:
        raise InputError(f"alarms list: takes no ID (got {args.id})")
    if args.action != "list" and args.id is None:
        raise InputError(f"alarms {args.action}: give the alarm's ID (see heliocal alarms list)")
    if (args.duration is not None) != (args.action == "shelve"):
        raise InputError("--for DURATION goes with shelve, and shelve needs it")
    duration = parse_duration(args.duration) if args.duration is not None else None
    if args.id is not None:
        if not is_ascii_index(args.id) or len(args.id) > 18:
            raise InputError(f"alarms {args.action}: ID must be an alarm's number, got {args.id!r}")
        args.id = int(args.id)
    with CampaignStore(database(args)) as store:
        book = AlarmBook(store)
        if args.action == "list":
            alarms = book.alarms(include_normal=args.all)
        elif args.action == "ack":
            alarms = [book.acknowledge(args.id, cli_user(), args.comment)]
        elif args.action == "shelve":
            alarms = [book.shelve(args.id, cli_user(), duration, args.comment)]
        else:
            alarms = [book.unshelve(args.id, cli_user())]
    now = now_utc()
    out = [a.to_json(now) for a in alarms]
    if args.json:
        print_json(out if args.action == "list" else out[0])
        return 0
    if args.action == "list" and not out:
        print("no alarms")
    for a in out:
        who = f", acknowledged by {a['acknowledged_by']}" if a["acknowledged_by"] else ""
        shelf = f", shelved until {a['shelved_until_utc']}" if a["shelved_until_utc"] else ""
        print(f"{a['id']:>4}  {a['priority']:<6} {a['state']:<12} {a['condition']:<20} {a['source']:<14} "
              f"{a['message']} (raised {a['raised_utc']}, {a['count']}x{who}{shelf})")
    return 0
