"""``heliocal sim lamp-panel``: a simulated lamp panel on Modbus TCP, on its own.

Contract::

    heliocal sim lamp-panel [--config C] [--port P] [--json]

It serves the panel of docs/lamps.md ("Wiring": coil N switches channel N, discrete input N
confirms it) on 127.0.0.1:P (default 0: a free port) for the channels of C (every lamp of
``light_sources``, then ``fiducials:<target>`` for each target whose camera registers), each
lamp lighting when its coil is written on; prints one line (``--json``: ``{"ok": true,
"lamps": {...}}``, the ``lamps:`` section that reaches it) and serves until SIGINT or SIGTERM.
"""

from __future__ import annotations

from controller.commands._numbers import Number
from controller.commands.common import (
    add_config_option,
    add_json_option,
    print_json,
    serve_until,
    stop_on_signals,
)
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("lamp-panel", help="serve a simulated lamp panel on Modbus TCP",
                              description=__doc__.split("\n\n")[0])
    add_config_option(p)
    p.add_argument("--port", type=Number(0, 65535, integer=True), default=0, metavar="P",
                   help="TCP port on 127.0.0.1 (default 0: a free one)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from controller.config import load_config
    from simplant.devices.lamp_panel import PanelLamps, SimLampPanel, panel_channels

    channels = panel_channels(load_config(args.config))
    if not channels:
        raise InputError(f"{args.config}: no lamp and no registering camera: the panel would have no channel")
    stop = stop_on_signals()
    panel = SimLampPanel(PanelLamps(channels), channels)
    try:
        port = panel.start(port=args.port)
    except OSError as exc:
        raise InputError(f"--port {args.port}: {exc.strerror or exc}") from None
    try:
        section = {"driver": "modbus-tcp", "host": "127.0.0.1", "port": port, "unit": panel.unit,
                   "channels": channels}
        if args.json:
            print_json({"ok": True, "lamps": section})
        else:
            listed = ", ".join(f"{name}={i}" for name, i in channels.items())
            print(f"serving a lamp panel on 127.0.0.1:{port} unit {panel.unit}, channels {listed}; "
                  "stop with Ctrl-C or SIGTERM")
        serve_until(stop)
    finally:
        panel.stop()
    return 0
