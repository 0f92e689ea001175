"""Link options shared by ``heliocal drive`` and ``heliocal sim firmware``: parsing the
``--serial``/``--modbus-tcp``/``--modbus-rtu`` values into config link models, and the rule
that picks a heliostat's axes from the plant configuration for a link and unit.

Rule (docs/serial-link.md): the heliostat whose configured link has the same kind, the same
device (paths compared after resolving symlinks) or host:port, and the same bus address or
unit id; if none matches, the first heliostat of the configuration.
"""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import ValidationError

from controller.commands.common import DEFAULT_CONFIG
from controller.config import (
    Heliostat,
    ModbusRtuLink,
    ModbusTcpLink,
    PlantConfig,
    SerialLink,
    load_config,
)
from controller.errors import InputError


def add_link_options(parser, serial_flag: str) -> None:
    """Mutually exclusive, required link options; ``serial_flag`` is ``--serial`` or ``--serial-link``."""
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument(serial_flag, dest="serial", metavar="PATH",
                       help="serial device (or symlink to a pty) of the RS-485 bus")
    group.add_argument("--modbus-tcp", metavar="HOST:PORT", help="Modbus TCP endpoint")
    group.add_argument("--modbus-rtu", metavar="PATH", help="Modbus RTU serial device")


def parse_units(text: str) -> list[int]:
    """``"1,2"`` -> ``[1, 2]``; each must be a bus address / unit id 1..247."""
    units = []
    for part in text.split(","):
        try:
            u = int(part.strip())
        except ValueError:
            raise InputError(f"--units: {part.strip()!r} is not an integer (expected e.g. 1,2)") from None
        if not 1 <= u <= 247:
            raise InputError(f"--units: {u} is outside the bus address range 1..247")
        if u in units:
            raise InputError(f"--units: {u} is given twice")
        units.append(u)
    return units


def host_port(text: str, option: str = "--modbus-tcp") -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise InputError(f"{option}: expected HOST:PORT, got {text!r}")
    try:
        p = int(port)
    except ValueError:
        raise InputError(f"{option}: port {port!r} is not an integer") from None
    if not 0 <= p <= 65535:
        raise InputError(f"{option}: port {p} is outside 0..65535")
    return host, p


def link_model(args, unit: int, baud: int = 115200):
    """The config link model (SerialLink, ModbusTcpLink, ModbusRtuLink) for the CLI options."""
    try:
        if args.serial:
            return SerialLink(kind="serial", device=args.serial, address=unit, baud=baud)
        if args.modbus_tcp:
            host, port = host_port(args.modbus_tcp)
            return ModbusTcpLink(kind="modbus-tcp", host=host, port=port, unit=unit)
        return ModbusRtuLink(kind="modbus-rtu", device=args.modbus_rtu, unit=unit, baud=baud)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = {"address": "--unit", "unit": "--unit", "port": "port", "baud": "--baud"}.get(
            str(err["loc"][-1]), str(err["loc"][-1]))
        raise InputError(f"{key}: {err['msg']}") from None


def load_plant(config: str | None, required: bool) -> PlantConfig | None:
    """Load ``config`` (or the default). With ``required`` False, a *default* config that does
    not exist gives None instead of an error; an explicit ``--config`` must always load."""
    path = config or DEFAULT_CONFIG
    if config is None and not required and not Path(path).is_file():
        return None
    return load_config(path)


def _same_path(a: str, b: str) -> bool:
    return a == b or os.path.realpath(a) == os.path.realpath(b)


def heliostat_for(plant: PlantConfig, link) -> tuple[Heliostat, bool]:
    """The heliostat for ``link`` by the module's rule, and whether its link matched."""
    for h in plant.heliostats:
        c = h.link
        if c.kind != link.kind:
            continue
        if c.kind == "serial" and _same_path(c.device, link.device) and c.address == link.address:
            return h, True
        if c.kind == "modbus-tcp" and (c.host, c.port, c.unit) == (link.host, link.port, link.unit):
            return h, True
        if c.kind == "modbus-rtu" and _same_path(c.device, link.device) and c.unit == link.unit:
            return h, True
    return plant.heliostats[0], False
