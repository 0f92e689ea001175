"""``heliocal sim plant``: the simulated plant of a configuration as one process on real
transports — a rehearsal field to point the product at (docs/getting-started.md).

Contract::

    heliocal sim plant --config C --write-config OUT.yaml [--speedup X] [--seed S] [--json]

It serves every device of C's field on a real transport (the drives as C's links say: serial
firmware on ptys, Modbus TCP on 127.0.0.1; the lamp panel on Modbus TCP, 127.0.0.1; each
target's camera as two GigE Vision imagers on loopback addresses 127.0.0.2 and up), waits until
each answers, writes OUT.yaml — C's field as C gives it with the devices' addresses — prints one
line (JSON with ``--json``: ``{"ok": true, "config": ..., "heliostats": N, "drives": [...],
"lamp_panel": "127.0.0.1:PORT", "cameras": {target: [low, high]}}``), serves until SIGINT or
SIGTERM and then removes what it created (OUT.yaml, its ptys and files). Exit 2: a bad C, an
OUT.yaml that exists already; 1: a device that does not come up.
"""

from __future__ import annotations

from pathlib import Path

from controller.commands._numbers import SEED, Number
from controller.commands.common import (
    add_config_option,
    add_json_option,
    print_json,
    serve_until,
    stop_on_signals,
)
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("plant", description=__doc__.split("\n\n")[0],
                              help="serve the simulated plant on real transports (a rehearsal field)")
    add_config_option(p)
    p.add_argument("--write-config", required=True, metavar="OUT",
                   help="write the configuration of the served field here (removed on exit; must not exist)")
    p.add_argument("--speedup", type=Number(0, 1000, lo_open=True), default=1.0, metavar="X",
                   help="run the plant clock (actuator physics) X times faster than real time (default 1)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="the hidden heliostats' errors and the noise (default 0)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.config import load_config

    cfg = load_config(args.config)
    out = Path(args.write_config)
    if out.exists() or out.is_symlink():
        raise InputError(f"--write-config {out}: exists already (the plant writes a new file and removes it "
                         "when it stops; remove it or choose another name)")
    if not out.parent.is_dir():
        raise InputError(f"--write-config {out}: no folder {out.parent}")
    from simplant.rehearsal import RehearsalPlant
    from simplant.settings import SimulationSettings

    stop = stop_on_signals()
    settings = SimulationSettings(clock_speedup=args.speedup, seed=args.seed)
    plant = RehearsalPlant(args.config, cfg, out, settings)
    try:
        ready = plant.start()
        if args.json:
            print_json(ready)
        else:
            cams = "; ".join(f"{t} {low} / {high}" for t, (low, high) in ready["cameras"].items())
            print(f"serving the simulated plant of {args.config}: {ready['heliostats']} heliostats on "
                  f"{', '.join(ready['drives'])}; lamp panel {ready['lamp_panel']}; cameras (GigE LOW / "
                  f"HIGH) {cams}; configuration {out}; stop with Ctrl-C or SIGTERM")
        serve_until(stop)
    finally:
        plant.stop()
    return 0
