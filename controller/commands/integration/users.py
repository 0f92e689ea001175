"""``heliocal users``: operator accounts and their roles (docs/plant-integration.md, "Operators
and roles").

Contract (scripts depend on it)::

    heliocal users add NAME --role viewer|operator|engineer --password-file FILE [--db DB]
    heliocal users remove NAME [--db DB]
    heliocal users list [--db DB] [--json]

FILE holds the password on its one line (8 to 1024 printable characters); it is stored as an
scrypt hash. The
console and the OPC UA server (``heliocal opcua``) sign in with these accounts. ``list --json``:
``[{"name", "role", "created_utc"}, ...]``. Adding and removing are audited. Exit 0, 2 bad input
(a name that exists or does not, a bad role, an unreadable or short password file).
"""

from __future__ import annotations

from controller.commands.common import add_json_option, print_json
from controller.commands.integration._plant import add_db_option, cli_user, database, read_password
from controller.errors import InputError

ROLES = ("viewer", "operator", "engineer")  # controller.storage.users.ROLES


def register(subparsers) -> None:
    p = subparsers.add_parser("users", help="operator accounts: add, remove, list",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("action", choices=("add", "remove", "list"), help="add, remove or list")
    p.add_argument("name", nargs="?", metavar="NAME", help="the account's name (add, remove)")
    p.add_argument("--role", choices=ROLES, help="the account's role (add)")
    p.add_argument("--password-file", metavar="FILE", help="file holding the password on its one line (add)")
    add_db_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.storage.db import CampaignStore
    from controller.storage.users import Accounts, check_password

    if args.action == "list" and args.name:
        raise InputError(f"users list: takes no NAME (got {args.name!r})")
    if args.action != "list" and not args.name:
        raise InputError(f"users {args.action}: give the account's NAME")
    if args.action == "add" and (args.role is None or args.password_file is None):
        raise InputError("users add: needs --role and --password-file")
    if args.action != "add" and (args.role or args.password_file):
        raise InputError(f"users {args.action}: --role and --password-file go with add")
    password = check_password(read_password(args.password_file), args.password_file) \
        if args.action == "add" else None
    with CampaignStore(database(args, must_exist=args.action != "add")) as store:
        accounts = Accounts(store)
        if args.action == "add":
            acc = accounts.add(args.name, args.role, password, by=cli_user())
            out = {"ok": True, "action": "add", **acc.to_json()}
        elif args.action == "remove":
            accounts.remove(args.name, by=cli_user())
            out = {"ok": True, "action": "remove", "name": args.name}
        else:
            listed = [a.to_json() for a in accounts.list()]
            if args.json:
                print_json(listed)
            else:
                for a in listed:
                    print(f"{a['name']:<24} {a['role']:<9} since {a['created_utc']}")
                if not listed:
                    print("no accounts (add one: heliocal users add NAME --role ROLE --password-file FILE)")
            return 0
    if args.json:
        print_json(out)
    else:
        print(f"user {args.name}: {'added as ' + args.role if args.action == 'add' else 'removed'}")
    return 0
