"""``heliocal console --config C --db DB [--simulate]``: the field console, a local web page.

Pages for the field map, each heliostat (drive status, model, history, beam image; jog, move,
park, stow), guided commissioning, the campaign (start, pause, abort, live queue) and the
reports, updated live by server-sent events. Listens on 127.0.0.1:8080 by default; another
address needs ``--token`` or ``--token-file``, and then every state-changing request must carry
the header ``X-Heliocal-Token``. Every move takes the CLI's validated path; while a campaign
runs only its state machine drives. The camera is the configuration's ``camera.driver`` (gige,
file), opened as ``campaign run`` opens it, or ``--camera-manifest`` / ``--simulate``. See
docs/console.md.
"""

from __future__ import annotations

import argparse
import ipaddress
import socket
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from controller.commands._id_lists import split_ids
from controller.commands._numbers import SEED, Number
from controller.commands.common import (
    add_config_option,
    add_field_change_option,
    check_camera,
    check_db_field,
)
from controller.errors import InputError
from controller.io.yaml_files import read_text

MIN_TOKEN_CHARS = 12


def register(subparsers) -> None:
    p = subparsers.add_parser("console", help="field console: a local web page over the plant",
                              description=__doc__.splitlines()[0])
    add_config_option(p)
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite, created if missing)")
    p.add_argument("--simulate", action="store_true", help="run the console on the embedded simulated plant")
    p.add_argument("--seed", type=SEED, default=0, help="simulation seed (with --simulate; default 0)")
    p.add_argument("--clock-speedup", type=Number(0, 1000, lo_open=True), default=20.0, metavar="X",
                   help="plant seconds per wall second of the simulated plant (with --simulate; default 20)")
    p.add_argument("--heliostats", default=None, metavar="IDS",
                   help="comma-separated heliostat ids the console shows and drives (default: all)")
    p.add_argument("--camera-manifest", default=None, metavar="FILE",
                   help="replay recorded frame pairs as the camera (FileCamera; without --simulate)")
    p.add_argument("--library", default=None, metavar="LIB",
                   help="error library YAML (matching; commissioning stores reference cases in it)")
    p.add_argument("--reports", default=None, metavar="DIR",
                   help="folder with confusion reports (heliocal report confusion) to show")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=Number(0, 65535, integer=True), default=8080,
                   help="TCP port (default 8080; 0 picks a free one)")
    tok = p.add_mutually_exclusive_group()
    tok.add_argument("--token", default=None, metavar="T",
                     help="token every state-changing request must send as X-Heliocal-Token")
    tok.add_argument("--token-file", default=None, metavar="F", help="read the token from file F")
    p.add_argument("--run-dir", default=None, metavar="DIR",
                   help="simulation run directory (ptys; with --simulate; default a temporary folder)")
    add_field_change_option(p)
    p.set_defaults(func=run)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def read_token(args: argparse.Namespace) -> str | None:
    """The token of ``--token`` / ``--token-file`` (stripped), or None; InputError when it is
    unreadable, too short, or missing while ``--host`` is not a loopback address."""
    token = args.token
    if args.token_file:
        try:  # the bounded reader: size, UTF-8
            token = read_text(args.token_file, "token file", max_bytes=4096).strip()
        except InputError as exc:
            raise InputError(f"--token-file {exc}") from None
    if token is not None and not (token.isascii() and token.isprintable()):  # it travels in a header
        raise InputError(f"{'--token-file ' + args.token_file if args.token_file else '--token'}: the token "
                         "must be printable ASCII text")
    if token is not None and len(token.strip()) < MIN_TOKEN_CHARS:
        raise InputError(f"{'--token-file ' + args.token_file if args.token_file else '--token'}: the token "
                         f"must have at least {MIN_TOKEN_CHARS} characters")
    if token is None and not is_loopback(args.host):
        raise InputError(f"--host {args.host}: listening beyond this machine needs --token T or "
                         "--token-file F (every state-changing request must then carry it)")
    return token.strip() if token is not None else None


def _listen(host: str, port: int) -> socket.socket:
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be 0 … 65535, got {port}")
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
    except OSError as exc:
        raise InputError(f"--host/--port: cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    sock.listen(64)
    return sock


def run(args: argparse.Namespace) -> int:
    from controller.config import load_config

    token = read_token(args)
    cfg = load_config(args.config)
    ids = [h.id for h in cfg.heliostats]
    if args.heliostats is not None:
        ids = split_ids(args.heliostats, "--heliostats", cfg.heliostat)
    check_camera(cfg, args, "console")
    check_db_field(args.db, cfg, ids, args)  # the models it aims with were fitted on this field
    if args.reports and not Path(args.reports).is_dir():
        raise InputError(f"--reports {args.reports}: not a folder")
    from controller.recognition.library_io import load_library_if_present

    library = load_library_if_present(args.library)
    sock = _listen(args.host, args.port)
    try:
        return serve(cfg, args, ids, token, sock, library)
    finally:
        sock.close()


@contextmanager
def _field(cfg, args, ids, store, library):
    """The console's field (controller.commands.field) and its plant hooks."""
    from controller.commands.field import real_field
    from controller.console.backend import PlantHooks

    if not args.simulate:
        with real_field(cfg, args.config, store, camera_manifest=args.camera_manifest) as fs:
            fs.field.library = library
            yield fs.field, PlantHooks()
        return
    from controller.commands.simulated import run_directory, simulated_field, simulation_settings
    from controller.storage.nights import NightBook

    settings = simulation_settings(seed=args.seed, clock_speedup=args.clock_speedup)
    night = NightBook(store).next_index()
    with run_directory(args.run_dir, "heliocal-console-") as run_dir, \
            simulated_field(cfg, args.config, store, run_dir, ids, settings, night=night,
                            library=library) as fs:  # the console builds no library: --library or none
        plant = fs.plant
        yield fs.field, PlantHooks(safety=plant.safety.report, set_night=plant.set_night,
                                   label=f"simulated plant (seed {settings.seed})")


def serve(cfg, args, ids, token, sock, library) -> int:
    """Run the console until Ctrl-C / SIGTERM; then stop a running campaign (beams parked),
    park what the console moved and release the database."""
    import uvicorn

    from controller.console.app import create_app
    from controller.console.backend import Console
    from controller.storage.db import CampaignStore

    with CampaignStore(args.db) as store, tempfile.TemporaryDirectory(prefix="heliocal-console-") as work, \
            _field(cfg, args, ids, store, library) as (plant, hooks):
        console = Console(plant, heliostat_ids=ids, library_path=args.library, hooks=hooks, work_dir=work,
                          reports_dir=args.reports)
        app = create_app(console, token=token)
        console.start()

        class Server(uvicorn.Server):
            def handle_exit(self, sig, frame) -> None:
                console.bus.close()  # end the live streams so the server can stop at once
                super().handle_exit(sig, frame)

        server = Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=2, lifespan="off"))
        host, port = sock.getsockname()[:2]
        where = f"[{host}]" if ":" in host else host
        print(f"heliocal console: http://{where}:{port}/ ({console.hooks.label}, {len(ids)} heliostats; "
              f"{'token required' if token else 'no token'}; Ctrl-C to stop)", file=sys.stderr, flush=True)
        try:
            server.run(sockets=[sock])
        finally:
            done = console.close()
            for hid, what in done.items():
                print(f"heliocal console: {hid} {what['action']}", file=sys.stderr)
    return 0
