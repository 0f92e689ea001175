"""The simulated plant's lamp panel: Modbus TCP on 127.0.0.1, wired to the plant's lamps.

As on a field panel (docs/lamps.md, "Wiring"), channel N is coil N — writing it (function 05,
or 15) switches the plant's lamp, so the lamp the simulated cameras render with is the one the
panel lit — and discrete input N, which reports whether the plant's lamp is actually lit
(function 02). Coils read back (function 01) what was last written. Channels are the lamps of
``light_sources`` and ``fiducials:<target id>`` for every target whose camera registers
through the lamp panel (:func:`panel_channels`).

Served by the pinned pymodbus' ``SimDevice`` datastore on its own asyncio loop thread; the
async ``action`` callback applies coil writes to the plant and fills the bit tables from the
plant on every read. The server is stopped through its own ``shutdown()``, never pymodbus'
class-global "stop server", so it runs and stops independently of the plant's Modbus drive
server (:class:`simplant.firmware.modbus.ModbusSimServer`).

Fault hooks for tests: :attr:`SimLampPanel.no_confirm` — a lamp whose coil is written but
which stays dark and never confirms (a blown lamp, a tripped breaker); :attr:`no_light` — a
lamp that confirms (its input follows the coil) but gives no light (a sensor that lies: the
controller cannot tell, the scoring can); :attr:`stuck_lit` — a lamp that stays lit when
switched off (a welded contactor: its coil reads off, its input still confirms lit).
"""

from __future__ import annotations

import asyncio
import logging
import threading
from types import SimpleNamespace

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from controller.lamp_config import FIDUCIALS

logging.getLogger("pymodbus").addHandler(logging.NullHandler())

_WRITE_COILS = (5, 15)
_READ = {1: "coils", 5: "coils", 15: "coils", 2: "inputs"}  # a write reads its coils back


def panel_channels(cfg) -> dict[str, int]:
    """The simulated panel's channels for PlantConfig ``cfg``: every lamp of ``light_sources``
    (coils 0.. in config order), then ``fiducials:<target>`` for each target whose camera
    registers and has no ``camera.registration.lamp_command`` of its own."""
    names = [s.id for s in cfg.light_sources if s.kind == "lamp"]
    for t in cfg.targets:
        reg = cfg.camera_of(t.id).registration
        if reg is not None and not reg.lamp_command:
            names.append(FIDUCIALS + t.id)
    return {name: i for i, name in enumerate(names)}


class SimLampPanel:
    """The lamp panel of ``plant`` (a :class:`simplant.plant.SimulatedPlant`) on Modbus unit
    ``unit``. :meth:`start` returns the port; :meth:`stop` ends serving (idempotent)."""

    def __init__(self, plant, channels: dict[str, int], unit: int = 1) -> None:
        self.plant = plant
        self.channels = dict(channels)
        self.unit = unit
        self._name_of = {i: name for name, i in channels.items()}
        self.size = 16 * ((max(channels.values()) + 16) // 16)  # whole 16-bit words
        # The coils start as the plant's lamps are: a panel wired to lamps already lit.
        self.coils = [self._name_of.get(i) is not None and self.actual(self._name_of[i])
                      for i in range(self.size)]
        self.no_confirm: set[str] = set()
        self.no_light: set[str] = set()
        self.stuck_lit: set[str] = set()
        self.writes: list[tuple[str, bool]] = []  # (channel, on) in the order received
        self.port: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: ModbusTcpServer | None = None

    # -- the plant side --------------------------------------------------------------------
    def actual(self, channel: str) -> bool:
        """Whether the plant's lamp of ``channel`` is lit now (the simulation's truth)."""
        if channel.startswith(FIDUCIALS):
            cam = self.plant.cameras.get(channel.removeprefix(FIDUCIALS))
            return bool(cam is not None and cam.fiducials_lit)
        return self.plant.lamp_lit(channel)

    def confirmation(self, channel: str) -> bool:
        """Discrete input of ``channel``: the lamp's state, or the coil for a lying sensor."""
        return self.coils[self.channels[channel]] if channel in self.no_light else self.actual(channel)

    def _write(self, index: int, on: bool) -> None:
        self.coils[index] = on
        channel = self._name_of.get(index)
        if channel is None:
            return  # a spare coil: wired to nothing
        self.writes.append((channel, on))
        if not on and channel in self.stuck_lit:
            return  # the contactor does not open: the lamp stays as it is
        light = on and channel not in self.no_confirm and channel not in self.no_light
        if channel.startswith(FIDUCIALS):
            self.plant.set_fiducials(light, channel.removeprefix(FIDUCIALS))
        else:
            self.plant.switch_lamp(channel, light)

    # -- the Modbus side -------------------------------------------------------------------
    async def _action(self, fc, start, address, count, registers, values):
        if fc in _WRITE_COILS and values is not None:
            if address + len(values) > self.size:
                return ExcCodes.ILLEGAL_ADDRESS
            for k, v in enumerate(values):
                self._write(address + k, bool(v))
            return None
        table = _READ.get(fc)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        names = [self._name_of.get(i) for i in range(self.size)]
        bits = self.coils if table == "coils" else [n is not None and self.confirmation(n) for n in names]
        for word in range(self.size // 16):
            registers[word] = sum(1 << b for b in range(16) if bits[16 * word + b])
        return None

    def _device(self) -> SimDevice:
        bits = [SimData(0, values=[False] * self.size, datatype=DataType.BITS)]
        # The datastore needs a holding and an input table; the action refuses their functions.
        regs = [SimData(0, count=1, datatype=DataType.REGISTERS)]
        return SimDevice(id=self.unit, simdata=(bits, list(bits), regs, list(regs)), action=self._action)

    def start(self, rtu_framing: bool = False, port: int = 0) -> int:
        """Serve on 127.0.0.1, ``port`` (0: an ephemeral one); the port. ``rtu_framing``: Modbus
        RTU frames over the TCP connection (a serial gateway; a ``modbus-rtu`` client reaches it
        through pyserial's ``socket://127.0.0.1:PORT``). OSError when the port is taken."""
        if self._server is not None:
            return self.port
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="lamp-panel", daemon=True)
        self._thread.start()

        async def make():  # pymodbus servers are built inside their running loop
            server = ModbusTcpServer([self._device()], address=("127.0.0.1", port),
                                     framer=FramerType.RTU if rtu_framing else FramerType.SOCKET)
            await server.serve_forever(background=True)
            return server

        try:
            self._server = asyncio.run_coroutine_threadsafe(make(), self._loop).result(5.0)
        except RuntimeError as exc:  # pymodbus' "Could not start listen": the port is taken
            self.stop()
            raise OSError(f"cannot listen on 127.0.0.1:{port} ({exc})") from None
        except BaseException:
            self.stop()
            raise
        self.port = self._server.transport.sockets[0].getsockname()[1]
        return self.port

    def stop(self) -> None:
        """Shut this server down (its own ``shutdown()``) and end its loop thread."""
        if self._server is not None:
            asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(5.0)
            self._server = None
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)
            self._loop.close()
            self._loop = None


class PanelLamps:
    """Lamps wired to a panel and nothing else (``heliocal sim lamp-panel``): each one lights
    when its coil is written on — what :class:`SimLampPanel` asks of a plant."""

    def __init__(self, channels: dict[str, int]) -> None:
        self._lit: set[str] = set()
        self.cameras = {name.removeprefix(FIDUCIALS): SimpleNamespace(fiducials_lit=False)
                        for name in channels if name.startswith(FIDUCIALS)}

    def lamp_lit(self, lamp_id: str) -> bool:
        return lamp_id in self._lit

    def switch_lamp(self, lamp_id: str, on: bool) -> None:
        (self._lit.add if on else self._lit.discard)(lamp_id)

    def set_fiducials(self, on: bool, target: str) -> None:
        self.cameras[target].fiducials_lit = bool(on)
