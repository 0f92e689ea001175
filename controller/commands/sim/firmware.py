"""``heliocal sim firmware``: simulated heliostat drive controllers on a pty or Modbus.

Contract::

    heliocal sim firmware --serial-link PATH [--units 1,2] [--config configs/demo.yaml]
    heliocal sim firmware --modbus-tcp 127.0.0.1:PORT [--units 1,2]
    heliocal sim firmware --modbus-rtu PATH [--units 1,2]

It prints one line when it is ready (JSON with ``--json``: ``{"ok": true, "link": ...,
"device": ..., "port": ..., "units": [...]}``), serves until SIGINT/SIGTERM and then removes
the symlink PATH. Each unit's axes come from the configuration by the rule of
:mod:`controller.commands.devices._links`.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

from controller.commands._numbers import Number
from controller.commands.common import (
    DEFAULT_CONFIG,
    add_json_option,
    print_json,
    serve_until,
    stop_on_signals,
)
from controller.commands.devices._links import (
    add_link_options,
    heliostat_for,
    host_port,
    load_plant,
    parse_units,
)
from controller.errors import HeliocalError, InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("firmware", help="serve simulated drive controllers on a pty or Modbus",
                              description=__doc__.split("\n\n")[0])
    add_link_options(p, "--serial-link")
    p.add_argument("--units", default="1", help="bus addresses / unit ids to serve (default 1)")
    p.add_argument("--config", default=DEFAULT_CONFIG, metavar="FILE",
                   help=f"plant configuration for the axes (default {DEFAULT_CONFIG})")
    p.add_argument("--speedup", type=Number(0, 1000, lo_open=True), default=1.0, metavar="X",
                   help="run the actuator physics X times faster than real time (default 1)")
    add_json_option(p)
    p.set_defaults(func=run)


def build_controllers(plant, args, units: list[int], speedup: float) -> dict:
    """One SimController per unit, with the axes of the heliostat the link rule picks."""
    from simplant.firmware.physics import SimController, axis_params_from_config

    t0 = time.monotonic()

    def clock() -> float:
        return t0 + (time.monotonic() - t0) * speedup

    controllers = {}
    for unit in units:
        heliostat, _ = heliostat_for(plant, _link_key(args, unit))
        controllers[unit] = SimController(
            unit, axis_params_from_config(heliostat.axes.azimuth),
            axis_params_from_config(heliostat.axes.elevation), clock=clock)
    return controllers


def _link_key(args, unit: int) -> SimpleNamespace:
    """The link fields the heliostat rule compares (no validation: ``--modbus-tcp`` may give
    port 0, meaning "any free port")."""
    if args.serial:
        return SimpleNamespace(kind="serial", device=args.serial, address=unit)
    if args.modbus_tcp:
        host, port = host_port(args.modbus_tcp)
        return SimpleNamespace(kind="modbus-tcp", host=host, port=port, unit=unit)
    return SimpleNamespace(kind="modbus-rtu", device=args.modbus_rtu, unit=unit)


def run(args) -> int:
    if not 0 < args.speedup <= 1000:
        raise InputError(f"--speedup must be in (0, 1000], got {args.speedup}")
    units = parse_units(args.units)
    plant = load_plant(args.config, required=True)
    if args.modbus_tcp:
        host_port(args.modbus_tcp)  # validate before building anything
    controllers = build_controllers(plant, args, units, args.speedup)
    stop = stop_on_signals()
    if args.serial:
        from simplant.firmware.serial import SerialSimFirmware

        server = SerialSimFirmware(controllers, args.serial)
        try:
            device = server.start()
        except OSError as exc:
            raise InputError(f"--serial-link {args.serial}: {exc}") from None
        ready = {"ok": True, "link": args.serial, "device": device, "units": units}
    else:
        try:
            from simplant.firmware.modbus import ModbusSimServer
        except ModuleNotFoundError as exc:
            raise HeliocalError(f"the Modbus simulator is not available: {exc}") from None
        server = ModbusSimServer(controllers)
        try:
            if args.modbus_tcp:
                host, port = host_port(args.modbus_tcp)
                bound = server.start_tcp(host, port)
                ready = {"ok": True, "link": f"{host}:{bound}", "port": bound, "units": units}
            else:
                device = server.start_rtu(args.modbus_rtu)
                ready = {"ok": True, "link": args.modbus_rtu, "device": device, "units": units}
        except OSError as exc:
            server.stop()
            option = "--modbus-tcp" if args.modbus_tcp else "--modbus-rtu"
            raise InputError(f"{option} {args.modbus_tcp or args.modbus_rtu}: {exc}") from None
    try:
        if args.json:
            print_json(ready)
        else:
            print(f"serving units {','.join(map(str, units))} on {ready['link']}"
                  + (f" ({ready['device']})" if "device" in ready else "")
                  + "; stop with Ctrl-C or SIGTERM")
        serve_until(stop)
    finally:
        server.stop()
    return 0
