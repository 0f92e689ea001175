"""The simulated plant's drives on their wires: the firmware of each serial bus on a pty, the
Modbus heliostats behind one server (TCP on 127.0.0.1, an ephemeral port; RTU on a pty), and
the configuration's links rewritten to reach them (:class:`simplant.plant.SimulatedPlant`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from simplant.firmware.physics import SimController


@dataclass
class Drives:
    """What serves the drives: ``serial`` firmware by the configured device, ``modbus`` (or
    None); ``paths``: configured device -> the pty (or its symlink) serving it; ``port``: the
    Modbus TCP port (or None)."""

    serial: dict[str, object] = field(default_factory=dict)
    modbus: object | None = None
    paths: dict[str, str] = field(default_factory=dict)
    port: int | None = None

    def rewrite(self, links: list[dict]) -> None:
        """Point the raw configuration's ``links`` (mappings, changed in place) at these servers."""
        for link in links:
            if link.get("device") in self.paths:
                link["device"] = self.paths[link["device"]]
            if link.get("kind") == "modbus-tcp" and self.port is not None:
                link["host"], link["port"] = "127.0.0.1", self.port

    def stop(self) -> None:
        for fw in self.serial.values():
            fw.stop()
        self.serial.clear()
        if self.modbus is not None:
            self.modbus.stop()
            self.modbus = None


def serve_drives(controllers: list[tuple[object, SimController]], dev_dir: Path) -> Drives:
    """Serve each (link, controller) of ``controllers``; ptys and symlinks go into ``dev_dir``.
    ValueError when two heliostats would share a station (several Modbus TCP gateways are
    served on one port) or for more than one Modbus RTU bus."""
    from simplant.firmware.modbus import ModbusSimServer
    from simplant.firmware.serial import SerialSimFirmware

    serial: dict[str, dict[int, SimController]] = {}
    tcp: dict[int, SimController] = {}
    rtu: dict[str, dict[int, SimController]] = {}
    for link, ctl in controllers:
        units = serial.setdefault(link.device, {}) if link.kind == "serial" else (
            tcp if link.kind == "modbus-tcp" else rtu.setdefault(link.device, {}))
        if link.station in units:
            raise ValueError(f"the simulated plant serves every Modbus TCP gateway on one port: unit "
                             f"{link.station} is configured twice")
        units[link.station] = ctl
    if len(rtu) > 1:
        raise ValueError("the simulated plant serves one Modbus RTU bus")
    drives = Drives()
    try:
        for device, ctls in serial.items():
            path = str(dev_dir / Path(device).name)
            drives.serial[device] = SerialSimFirmware(ctls, link_path=path)
            drives.serial[device].start()
            drives.paths[device] = path
        if tcp or rtu:
            drives.modbus = ModbusSimServer({**tcp, **next(iter(rtu.values()), {})})
            if tcp:
                drives.port = drives.modbus.start_tcp("127.0.0.1", 0)
            for device in rtu:
                drives.paths[device] = drives.modbus.start_rtu(str(dev_dir / Path(device).name))
    except BaseException:
        drives.stop()
        raise
    return drives
