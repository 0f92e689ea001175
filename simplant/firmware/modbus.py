"""Simulated Modbus actuator: the drive controller behind Modbus TCP and Modbus RTU.

The register map is ``registers.yaml`` (see MODBUS.md); the physics is
:class:`simplant.firmware.physics.SimController`, shared with the serial simulated firmware, so
both links move the same simulated axes the same way. The server is the pinned pymodbus
(3.16) ``SimDevice`` datastore: one ``SimDevice`` per unit id whose async ``action`` callback
refreshes the input registers from the controller on every read and validates and executes
every write (returning a Modbus exception code to refuse it).

Serving runs on an asyncio loop in a background thread. TCP listens on 127.0.0.1; RTU runs
on a pseudo-terminal null modem (two pty pairs bridged by a thread): the server opens one
end, clients open the other, optionally through a symlink. Every server is shut down through
its own ``shutdown()``, never pymodbus' class-global "stop server", so a TCP and an RTU
server (and several :class:`ModbusSimServer`) can live in one process.

Fault hooks for tests: :meth:`ModbusSimServer.pause` / :meth:`resume` stop and restart
serving (the physics keeps running), :attr:`silent_units` makes units ignore requests, and
unit ids without a controller never answer (as on an RS-485 bus).
"""

from __future__ import annotations

import asyncio
import logging
import re
import socket
import threading
from dataclasses import dataclass
from pathlib import Path

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from firmware_proto.faults import Reject
from firmware_proto.registers import Register, RegisterMap, load_register_map
from simplant.firmware.modbus_guard import ModbusGuard
from simplant.firmware.null_modem import NullModem
from simplant.firmware.physics import SimController

# Why a command was refused -> the Modbus exception code returned (MODBUS.md, "Exceptions").
_REJECT_EXCEPTION = {
    Reject.OUT_OF_RANGE: ExcCodes.ILLEGAL_VALUE,
    Reject.BAD_LIMITS: ExcCodes.ILLEGAL_VALUE,
    Reject.UNKNOWN_COMMAND: ExcCodes.ILLEGAL_VALUE,
    Reject.BAD_LENGTH: ExcCodes.ILLEGAL_VALUE,
    Reject.FAULT_ACTIVE: ExcCodes.DEVICE_FAILURE,
    Reject.BUSY: ExcCodes.DEVICE_BUSY,
}
_READ_FC = {3: "holding", 4: "input"}
_WRITE_FC = (6, 16)
_SOFT_LIMITS = ("az_soft_min_steps", "az_soft_max_steps", "el_soft_min_steps", "el_soft_max_steps")

logging.getLogger("pymodbus").addHandler(logging.NullHandler())


@dataclass(frozen=True)
class WriteRecord:
    """One write request that reached a unit (for tests: what did the device receive?)."""

    unit: int
    function_code: int
    address: int
    values: tuple[int, ...]
    decoded: dict
    exception: int | None


def _firmware_version(text: str) -> tuple[int, int, int]:
    m = re.search(r"(\d+)\.(\d+)\.(\d+)", text)
    return (int(m[1]), int(m[2]), int(m[3])) if m else (0, 0, 0)


class _Unit:
    """Register-level front end of one :class:`SimController` (one Modbus unit id).

    The holding-register image lives here, not in pymodbus' block, so TCP and RTU servers
    serving the same unit see the same setpoints."""

    def __init__(self, controller: SimController, regmap: RegisterMap) -> None:
        self.controller = controller
        self.map = regmap
        st = controller.status()
        self.holding: dict[str, int] = {
            "az_target_steps": st["az_target"], "el_target_steps": st["el_target"],
            "jog_az_steps": 0, "jog_el_steps": 0, "command": 0}
        self.last_reject = int(Reject.OK)
        self.counter = 0

    def input_values(self) -> dict[str, int]:
        st = self.controller.status()
        m = self.map
        bits = ((m.bit("status_bits", "moving") if st["moving"] else 0)
                | (m.bit("status_bits", "in_position") if st["in_position"] else 0)
                | (m.bit("status_bits", "limit_az") if st["limit_az"] else 0)
                | (m.bit("status_bits", "limit_el") if st["limit_el"] else 0)
                | (m.bit("status_bits", "fault") if st["faults"] else 0))
        major, minor, patch = _firmware_version(self.controller.firmware_version)
        return {"az_actual_steps": st["az_steps"], "el_actual_steps": st["el_steps"],
                "az_active_target_steps": st["az_target"], "el_active_target_steps": st["el_target"],
                "status_bits": bits, "fault_code": st["faults"], "last_reject": self.last_reject,
                "command_counter": self.counter & 0xFFFF, "device_type": self.map.device_type,
                "fw_version_major": major, "fw_version_minor": minor, "fw_version_patch": patch,
                "map_version": self.map.version,
                "az_hard_min_steps": self.controller.az.hard_min,
                "az_hard_max_steps": self.controller.az.hard_max,
                "el_hard_min_steps": self.controller.el.hard_min,
                "el_hard_max_steps": self.controller.el.hard_max}

    def holding_values(self) -> dict[str, int]:
        c = self.controller
        return {**self.holding, "az_soft_min_steps": c.az.soft_min, "az_soft_max_steps": c.az.soft_max,
                "el_soft_min_steps": c.el.soft_min, "el_soft_max_steps": c.el.soft_max}

    def fill(self, table: str, start: int, registers: list[int]) -> None:
        """Write the current image of ``table`` into pymodbus' block (in place)."""
        values = self.input_values() if table == "input" else self.holding_values()
        for name, value in values.items():
            reg = self.map[name]
            for i, word in enumerate(reg.encode(value)):
                registers[reg.address + i - start] = word

    def write(self, address: int, words: list[int]) -> tuple[ExcCodes | None, dict]:
        """Validate and apply a holding-register write. Returns (exception or None, decoded)."""
        end = address + len(words)
        touched: list[Register] = []
        for a in range(address, end):
            reg = self.map.at("holding", a)
            if reg is None or not reg.writable:
                return ExcCodes.ILLEGAL_ADDRESS, {}
            if reg.address < address or reg.end > end:
                return ExcCodes.ILLEGAL_ADDRESS, {}  # half of a 32-bit value: refuse torn writes
            if reg not in touched:
                touched.append(reg)
        new = {r.name: r.decode(words[r.address - address:r.end - address]) for r in touched}
        c = self.controller
        for name, p in (("az_target_steps", c.az), ("el_target_steps", c.el)):
            if name in new and not p.soft_min <= new[name] <= p.soft_max:
                return ExcCodes.ILLEGAL_VALUE, new  # never stored: MOVE cannot pick it up
        old_limits = (c.az.soft_min, c.az.soft_max, c.el.soft_min, c.el.soft_max)
        if any(n in new for n in _SOFT_LIMITS):
            limits = {**self.holding_values(), **new}
            refused = c.set_limits(*(limits[n] for n in _SOFT_LIMITS))
            if refused == Reject.BUSY:
                return ExcCodes.DEVICE_BUSY, new
            if refused != Reject.OK:
                return ExcCodes.ILLEGAL_VALUE, new
        image = {**self.holding, **{k: v for k, v in new.items() if k not in _SOFT_LIMITS}}
        if "command" in new:
            exc = self._execute(new["command"], image)
            if exc is not None:
                # A refused request stores nothing: limits written with it are taken back.
                if (c.az.soft_min, c.az.soft_max, c.el.soft_min, c.el.soft_max) != old_limits:
                    c.restore_limits(*old_limits)
                return exc, new
        self.holding = image
        return None, new

    def _execute(self, code: int, image: dict[str, int]) -> ExcCodes | None:
        codes = self.map["command"].codes
        c = self.controller
        if code == codes["none"]:
            return None
        actions = {
            codes["move"]: lambda: c.move_abs(image["az_target_steps"], image["el_target_steps"]),
            codes["jog"]: lambda: c.jog(image["jog_az_steps"], image["jog_el_steps"]),
            codes["stop"]: c.stop, codes["home"]: c.home, codes["stow"]: c.stow,
            codes["clear_fault"]: c.clear_fault,
        }
        result = actions[code]() if code in actions else Reject.UNKNOWN_COMMAND
        self.last_reject = int(result)
        if result == Reject.OK:
            self.counter += 1
            return None
        return _REJECT_EXCEPTION.get(result, ExcCodes.DEVICE_FAILURE)


def _listen_error(host: str, port: int) -> OSError:
    """pymodbus only says "Could not start listen"; bind once more to get the reason."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except OSError as exc:
        return OSError(exc.errno, f"cannot listen on {host}:{port}: {exc.strerror}")
    return OSError(f"cannot listen on {host}:{port}")


class ModbusSimServer:
    """Simulated Modbus drive controllers, one unit id per :class:`SimController`.

    Usage::

        sim = ModbusSimServer({1: ctrl1, 2: ctrl2})
        port = sim.start_tcp()            # 127.0.0.1, ephemeral port
        dev = sim.start_rtu("/tmp/bus3")  # pty; /tmp/bus3 -> /dev/pts/N
        ...
        sim.stop()
    """

    def __init__(self, controllers: dict[int, SimController], register_map: RegisterMap | None = None, *,
                 idle_timeout_s: float = 60.0, max_connections: int = 16) -> None:
        for unit in controllers:
            if not 1 <= unit <= 247:
                raise ValueError(f"Modbus unit ids are 1..247, got {unit}")
        self.map = register_map or load_register_map()
        self.controllers = dict(controllers)
        self.units = {u: _Unit(c, self.map) for u, c in controllers.items()}
        self.silent_units: set[int] = set()
        self.idle_timeout_s = idle_timeout_s  # TCP: a connection idle this long is closed
        self.max_connections = max_connections  # TCP: clients served at once
        self.writes: list[WriteRecord] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._servers: dict[str, object] = {}
        self.guard: ModbusGuard | None = None  # the TCP port's protocol checks
        self._tcp_address: tuple[str, int] | None = None
        self._rtu: tuple[NullModem, int, Path | None] | None = None

    # -- event loop -------------------------------------------------------------------------
    def _ensure_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.new_event_loop()
            self._thread = threading.Thread(target=self._loop.run_forever,
                                            name="modbus-sim", daemon=True)
            self._thread.start()
        return self._loop

    def _call(self, coro, timeout: float = 5.0):
        return asyncio.run_coroutine_threadsafe(coro, self._ensure_loop()).result(timeout)

    # -- the datastore ----------------------------------------------------------------------
    def _devices(self) -> list[SimDevice]:
        devices = [SimDevice(id=0, simdata=self._blocks(), action=self._silent)]
        for unit in self.units:
            async def action(fc, start, address, count, registers, values, _unit=unit):
                return self._action(_unit, fc, start, address, count, registers, values)
            devices.append(SimDevice(id=unit, simdata=self._blocks(), action=action))
        return devices

    def _blocks(self) -> tuple[list[SimData], list[SimData], list[SimData], list[SimData]]:
        """Separate tables (coils, discrete inputs, holding, input); undefined addresses are
        invalid, so pymodbus answers exception 2 there. Coil/discrete blocks exist only
        because the datastore needs one each; the action refuses their function codes."""
        def table(name: str) -> list[SimData]:
            return [SimData(r.address, count=r.count, datatype=DataType.REGISTERS,
                            readonly=not r.writable) for r in self.map.table(name)]
        bits = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        return (bits, list(bits), table("holding"), table("input"))

    @staticmethod
    async def _silent(*_args) -> None:
        # Cancelling the request handler drops the request without any answer.
        raise asyncio.CancelledError

    def _action(self, unit: int, fc: int, start: int, address: int, count: int,
                registers: list[int], values: list[int] | None) -> ExcCodes | None:
        if unit in self.silent_units:
            raise asyncio.CancelledError
        u = self.units[unit]
        if fc in _WRITE_FC and values is not None:
            words = [int(v) for v in values]
            exc, decoded = u.write(address, words)
            self.writes.append(WriteRecord(unit, fc, address, tuple(words), decoded,
                                           None if exc is None else int(exc)))
            return exc
        table = _READ_FC.get(fc) or ("holding" if fc in _WRITE_FC else None)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        u.fill(table, start, registers)
        return None

    # -- serving ----------------------------------------------------------------------------
    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Serve Modbus TCP on ``host:port`` (0: any free port). Returns the bound port."""
        if "tcp" in self._servers:
            raise RuntimeError("Modbus TCP is already being served")

        async def make():
            # pymodbus serves the registers on an internal loopback port; the public port is the
            # guard, which answers what the application protocol refuses (modbus_guard).
            server = ModbusTcpServer(self._devices(), address=("127.0.0.1", 0))
            await server.serve_forever(background=True)
            guard = ModbusGuard(("127.0.0.1", server.transport.sockets[0].getsockname()[1]),
                                idle_timeout_s=self.idle_timeout_s, max_connections=self.max_connections)
            try:
                bound = await guard.start(host, port)
            except OSError:
                await server.shutdown()
                raise RuntimeError(f"cannot listen on {host}:{port}") from None
            return server, guard, bound

        try:
            server, guard, bound = self._call(make())
        except RuntimeError:
            raise _listen_error(host, port) from None
        self._servers["tcp"] = server
        self.guard = guard
        self._tcp_address = (host, bound)
        return bound

    def start_rtu(self, path: str | None = None, baud: int = 115200) -> str:
        """Serve Modbus RTU on a pty. Returns the device clients open: ``path`` (a symlink
        created there, replacing an old symlink) or the pty slave's own name."""
        if "rtu" in self._servers:
            raise RuntimeError("Modbus RTU is already being served")
        modem = NullModem()
        link = None
        if path is not None:
            link = Path(path)
            if link.is_symlink():
                link.unlink()
            elif link.exists():
                modem.close()
                raise FileExistsError(f"{link} exists and is not a symlink; not replacing it")
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(modem.client_path)
        self._rtu = (modem, baud, link)
        self._start_rtu_server()
        return str(link) if link else modem.client_path

    def _start_rtu_server(self) -> None:
        modem, baud, _ = self._rtu

        async def make():
            server = ModbusSerialServer(self._devices(), port=modem.server_path, baudrate=baud)
            await server.serve_forever(background=True)
            return server

        self._servers["rtu"] = self._call(make())

    def pause(self, kind: str = "tcp") -> None:
        """Fault hook: stop serving ``kind`` ("tcp"/"rtu"); open connections are dropped.
        The controllers keep moving."""
        server = self._servers.pop(kind, None)
        if server is not None:
            self._call(server.shutdown())
        if kind == "tcp" and self.guard is not None:
            self._call(self.guard.close())
            self.guard = None

    def resume(self, kind: str = "tcp") -> None:
        """Fault hook: serve ``kind`` again, on the same port / pty as before."""
        if kind in self._servers:
            return
        if kind == "tcp" and self._tcp_address:
            self.start_tcp(*self._tcp_address)
        elif kind == "rtu" and self._rtu:
            self._start_rtu_server()
        else:
            raise RuntimeError(f"{kind} was never started")

    def stop(self) -> None:
        """Shut every server down, stop the loop thread and release the ptys (idempotent)."""
        for kind in list(self._servers):
            self.pause(kind)
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)
            self._loop.close()
            self._loop = None
        if self._rtu is not None:
            modem, _, link = self._rtu
            modem.close()
            if link is not None and link.is_symlink():
                link.unlink()
            self._rtu = None

    def __enter__(self) -> ModbusSimServer:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
