"""A lamp panel or PLC on Modbus TCP or RTU (docs/lamps.md, "Wiring").

Channel N of ``lamps.channels`` is coil N (0-based protocol address; written with function 05,
read back with 01: what the panel was told) and discrete input N (function 02: the lamp's own
confirmation that it is lit). One pymodbus client per panel; every request holds its lock, so
the panel may be used from several threads. A request without an answer is sent once more
after reconnecting; then :class:`LampError` names the panel, the channel and the register.
Modbus exception responses (pymodbus returns them) are :class:`LampError` too, with their code.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException

from controller.devices.lamp_panel import LampError, LampPanel, LampState

# pymodbus logs every timeout and refused connection at ERROR level; the errors raised here
# say it in one line instead.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

_EXCEPTIONS = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
               4: "server device failure", 6: "server device busy",
               10: "gateway path unavailable", 11: "gateway target failed to respond"}
_ATTEMPTS = 2  # the first request and one re-send after reconnecting


class ModbusLampPanel(LampPanel):
    """Use :meth:`from_config`; ``client`` is a pymodbus synchronous client."""

    def __init__(self, client, name: str, unit: int, channels: dict[str, int]) -> None:
        self._client = client
        self.name = name
        self.unit = unit
        self.index = dict(channels)
        self.channels = tuple(channels)
        self._lock = threading.Lock()

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
                if not self._client.connect():  # True at once when connected
                    failure = "cannot connect for"
                    continue
                try:
                    rr = call(self._client)
                except (ConnectionException, ModbusIOException, OSError):
                    # A late answer to this request must not be taken for the next one's.
                    self._client.close()
                    failure = "no answer to"
                    continue
                if rr.isError():
                    code = getattr(rr, "exception_code", None)
                    raise LampError(f"{self.name}: {what} of lamp {channel} refused with Modbus exception "
                                    f"{code} ({_EXCEPTIONS.get(code, 'unknown')})")
                return rr
        raise LampError(f"{self.name}: {failure} {what} of lamp {channel}")

    def switch(self, channel: str, on: bool) -> None:
        i = self.index[self.check_channel(channel)]
        self._request(f"writing coil {i}", channel,
                      lambda c: c.write_coil(i, bool(on), device_id=self.unit))

    def _bit(self, fc: int, channel: str) -> bool:
        i = self.index[self.check_channel(channel)]
        if fc == 1:
            rr = self._request(f"reading coil {i}", channel,
                               lambda c: c.read_coils(i, count=1, device_id=self.unit))
        else:
            rr = self._request(f"reading discrete input {i}", channel,
                               lambda c: c.read_discrete_inputs(i, count=1, device_id=self.unit))
        return bool(rr.bits[0])

    def commanded(self, channel: str) -> bool:
        """The channel's coil: what the panel was last told."""
        return self._bit(1, channel)

    def confirmed(self, channel: str) -> bool:
        return self._bit(2, channel)

    def states(self) -> list[LampState]:
        return [LampState(c, self.commanded(c), self.confirmed(c)) for c in self.channels]

    def close(self) -> None:
        with self._lock:
            self._client.close()
