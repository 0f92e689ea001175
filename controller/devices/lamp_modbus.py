"""A lamp panel or PLC on Modbus TCP or RTU (docs/lamps.md, "Wiring").

Channel N of ``lamps.channels`` is coil N (0-based protocol address; written with function 05,
read back with 01: what the panel was told) and discrete input N (function 02: the lamp's own
confirmation that it is lit). One pymodbus client per panel; every request holds its lock, so
the panel may be used from several threads. A request without an answer is sent once more
after reconnecting; then :class:`LampError` names the panel, the channel and the register.
Modbus exception responses (pymodbus returns them) are :class:`LampError` too, with their code.

A panel is recognised before it is trusted: every answer must be the Modbus response due to
the request (its function code; one data byte, padded with zeros, for the one bit read; the
coil and the value written), and before the first write on a connection the channel's coil
is read and checked so. An echo server passes a write (a write's response echoes it) but not
a read; a peer answering garbage or HTTP gives no valid frame. Either is refused in one line
naming the panel's address (:class:`NotALampPanel`).
"""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Callable

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from controller.devices.lamp_panel import LampError, LampPanel, LampState

# pymodbus logs every timeout and refused connection at ERROR level; the errors raised here
# say it in one line instead.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

_EXCEPTIONS = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
               4: "server device failure", 6: "server device busy",
               10: "gateway path unavailable", 11: "gateway target failed to respond"}
_ATTEMPTS = 2  # the first request and one re-send after reconnecting


class NotALampPanel(LampError):
    """The peer answered, but not as a Modbus lamp panel answers the request it was sent."""


class ModbusLampPanel(LampPanel):
    """Use :meth:`from_config`; ``client`` is a pymodbus synchronous client."""

    def __init__(self, client, name: str, unit: int, channels: dict[str, int]) -> None:
        self._client = client
        self.name = name
        self.unit = unit
        self.index = dict(channels)
        self.channels = tuple(channels)
        self._lock = threading.Lock()
        self._recognised = False  # this connection's peer answered a read as a panel does

    @classmethod
    def from_config(cls, cfg) -> ModbusLampPanel:
        """From a ``lamps:`` section with driver modbus-tcp or modbus-rtu. Connects lazily."""
        if cfg.driver == "modbus-tcp":
            client = ModbusTcpClient(cfg.host, port=cfg.port, timeout=cfg.timeout_s, retries=0)
        else:
            client = ModbusSerialClient(cfg.device, baudrate=cfg.baud, timeout=cfg.timeout_s, retries=0)
        return cls(client, cfg.name, cfg.unit, cfg.channels)

    def _request(self, what: str, channel: str, call: Callable[[object], object]):
        """One request with a re-send; the response, or LampError naming panel and channel."""
        failure = "no answer to"
        with self._lock:
            for _ in range(_ATTEMPTS):
                try:
                    connected = self._client.connect()  # True at once when connected
                except (OSError, ValueError):  # a host name the resolver cannot even encode
                    connected = False
                if not connected:
                    failure = "cannot connect for"
                    continue
                try:
                    rr = call(self._client)
                except (ModbusException, OSError):
                    # A late answer to this request must not be taken for the next one's.
                    self._close()
                    failure = "no answer to"
                    continue
                except NotALampPanel:
                    self._close()
                    raise
                except (ValueError, IndexError, KeyError, struct.error) as exc:  # a frame not decodable
                    self._close()
                    raise NotALampPanel(f"{self.name}: not a Modbus lamp panel: its answer to {what} "
                                        f"cannot be decoded ({type(exc).__name__})") from None
                if rr.isError():
                    code = getattr(rr, "exception_code", None)
                    raise LampError(f"{self.name}: {what} of lamp {channel} refused with Modbus exception "
                                    f"{code} ({_EXCEPTIONS.get(code, 'unknown')})")
                return rr
        raise LampError(f"{self.name}: {failure} {what} of lamp {channel}")

    def _close(self) -> None:
        self._client.close()
        self._recognised = False

    def switch(self, channel: str, on: bool) -> None:
        i = self.index[self.check_channel(channel)]

        def write(c):
            if not self._recognised:  # an echo would pass the write itself: its read first
                probe = self._read(c, 1, i)
                if probe.isError():
                    return probe
            rr = c.write_coil(i, bool(on), device_id=self.unit)
            if not rr.isError() and (rr.function_code != 5 or getattr(rr, "address", None) != i
                                     or list(getattr(rr, "bits", None) or [])[:1] != [bool(on)]):
                raise NotALampPanel(f"{self.name}: not a Modbus lamp panel: writing coil {i} "
                                    f"(function 05) was answered with function {rr.function_code}, "
                                    f"address {getattr(rr, 'address', None)}")
            return rr

        self._request(f"writing coil {i}", channel, write)

    def _read(self, c, fc: int, i: int):
        """Read bit ``i`` (function ``fc``: 1 coil, 2 discrete input) and check that the answer
        is the response due; NotALampPanel naming what came otherwise."""
        rr = c.read_coils(i, count=1, device_id=self.unit) if fc == 1 else \
            c.read_discrete_inputs(i, count=1, device_id=self.unit)
        if rr.isError():
            return rr
        bits = list(getattr(rr, "bits", None) or [])
        if rr.function_code != fc or len(bits) != 8 or any(bits[1:]):
            table = "coil" if fc == 1 else "discrete input"
            got = f"function {rr.function_code}"
            if rr.function_code == fc:
                got += f" with {len(bits) // 8} data bytes" if len(bits) != 8 else " with its unused bits set"
            raise NotALampPanel(f"{self.name}: not a Modbus lamp panel: reading {table} {i} (function "
                                f"{fc:02d}, one bit: one data byte, zero padded) was answered with {got}")
        self._recognised = True
        return rr

    def _bit(self, fc: int, channel: str) -> bool:
        i = self.index[self.check_channel(channel)]
        what = f"reading coil {i}" if fc == 1 else f"reading discrete input {i}"
        return bool(self._request(what, channel, lambda c: self._read(c, fc, i)).bits[0])

    def commanded(self, channel: str) -> bool:
        """The channel's coil: what the panel was last told."""
        return self._bit(1, channel)

    def confirmed(self, channel: str) -> bool:
        return self._bit(2, channel)

    def states(self) -> list[LampState]:
        return [LampState(c, self.commanded(c), self.confirmed(c)) for c in self.channels]

    def close(self) -> None:
        with self._lock:
            self._close()
