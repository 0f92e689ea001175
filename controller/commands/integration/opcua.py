"""``heliocal opcua``: the OPC UA server for the plant's control system (DCS/SCADA).

Contract (scripts depend on it; docs/plant-integration.md, "OPC UA")::

    heliocal opcua --config C --db DB [--endpoint opc.tcp://127.0.0.1:4840/heliocal]

Serves until SIGINT or SIGTERM. Namespace ``urn:heliocal``; the field, each heliostat (state,
last measurement, model and its age, predicted daytime error), each target and lamp, the night
(state, progress, predicted daytime error) and the alarm list, with the alarms as Alarms &
Conditions events and model changes as events. Methods (operator role): ``Lamps/AllOff``,
``Heliostats/<id>/Park``, ``Night/Start``, ``Night/Stop``, ``Alarms/Acknowledge``,
``Alarms/Shelve``. Sign-in: the ``users`` accounts (username and password); Basic256Sha256
Sign & Encrypt offered (``--require-encryption``: only that). The server's key and certificate
are made once in ``--pki DIR`` (default ``<DB>-opcua/`` beside the database). Exit 0 after a
signal, 2 bad input (no account in DB, a bad endpoint), 1 when it cannot listen.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from urllib.parse import urlsplit

from controller.commands._numbers import Number
from controller.commands.common import add_config_option
from controller.commands.integration._plant import add_db_option, database, heliostat_ids
from controller.errors import DeviceError, InputError

DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/heliocal"


def register(subparsers) -> None:
    p = subparsers.add_parser("opcua", help="OPC UA server for the plant's control system",
                              description=__doc__.split("\n\n")[0])
    add_config_option(p)
    add_db_option(p)
    p.add_argument("--endpoint", default=DEFAULT_ENDPOINT, metavar="URL",
                   help=f"opc.tcp://HOST:PORT/PATH to listen on (default {DEFAULT_ENDPOINT})")
    p.add_argument("--heliostats", default=None, metavar="IDS",
                   help="comma-separated ids shown (default: all)")
    p.add_argument("--pki", default=None, metavar="DIR",
                   help="folder of the server's key and certificate (default <DB>-opcua/)")
    p.add_argument("--poll", type=Number(0.05, 60), default=1.0, metavar="S",
                   help="seconds between two readings of the database (default 1)")
    p.add_argument("--require-encryption", action="store_true",
                   help="offer only Basic256Sha256 Sign & Encrypt")
    p.set_defaults(func=run)


def check_endpoint(url: str) -> tuple[str, int]:
    """(host, port) of an ``opc.tcp://HOST:PORT/PATH`` URL; InputError naming it otherwise."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != "opc.tcp" or not parts.hostname or port is None or not 1 <= port <= 65535:
        raise InputError(f"--endpoint {url!r}: give opc.tcp://HOST:PORT/PATH (e.g. {DEFAULT_ENDPOINT})")
    return parts.hostname, port


def run(args: argparse.Namespace) -> int:
    import asyncio

    from controller.config import load_config
    from controller.storage.db import CampaignStore
    from controller.storage.users import Accounts

    host, port = check_endpoint(args.endpoint)
    cfg = load_config(args.config)
    ids = heliostat_ids(args.heliostats, cfg) or [h.id for h in cfg.heliostats]
    db = database(args)
    with CampaignStore(db) as store:
        if not Accounts(store).any():
            raise InputError(f"{db}: no operator account; add one first (heliocal users add NAME --role "
                             "viewer|operator|engineer --password-file FILE)")
        pki = Path(args.pki) if args.pki else db.with_name(db.name + "-opcua")
        return asyncio.run(_serve(cfg, args, store, ids, pki))


async def _serve(cfg, args, store, ids, pki) -> int:
    import asyncio
    import signal

    from controller.opcua.server import HeliocalServer

    service = HeliocalServer(cfg, args.config, store, ids, endpoint=args.endpoint, pki_dir=pki,
                             poll_s=args.poll, require_encryption=args.require_encryption)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        try:
            await service.start()
        except OSError as exc:
            raise DeviceError(f"--endpoint {args.endpoint}: cannot listen ({exc.strerror or exc})") from None
        print(f"heliocal opcua: serving {args.endpoint} (namespace urn:heliocal, {len(ids)} heliostats; "
              "Ctrl-C to stop)", file=sys.stderr, flush=True)
        await service.run(stop)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await service.stop()
    print("heliocal opcua: stopped", file=sys.stderr, flush=True)
    return 0
