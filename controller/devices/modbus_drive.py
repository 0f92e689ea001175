"""Modbus drive: the :class:`~controller.devices.drive.Drive` interface over Modbus TCP or RTU.

Addresses, types and codes come from ``firmware_proto/registers.yaml`` (MODBUS.md). One
:class:`ModbusLink` (one pymodbus client) per physical link is shared by the drives of all
units on it; every request holds the link's lock, so drives may be used from several threads.

Behaviour on errors:

- no answer within ``timeout_s``: the request is re-sent up to ``retries`` times; the
  connection is closed first, so a dropped TCP connection is re-established (and a stale
  answer can never be taken for the next one). Then :class:`LinkError`.
- Modbus exception responses (pymodbus *returns* them): :class:`ModbusExceptionError`, a
  :class:`NakError` naming unit, function, register(s) and exception code;
  :class:`ModbusLimitError` (also a :class:`LimitError`, exit status 2) when the device
  refused a value as out of range.
- targets and jog deltas are written, read back and compared before the command register
  is written; a mismatch is a :class:`DriveError` and nothing moves.
- a command whose answer was lost is not blindly re-sent (a JOG would run twice): the
  device's ``command_counter`` says whether it was executed.

Out-of-range targets never reach the device: :meth:`Drive.move_abs` / :meth:`Drive.jog` check
the soft limits before anything is sent (:class:`LimitError`, exit status 2).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException

from controller.devices.drive import (
    AxisLimits,
    Drive,
    DriveError,
    DriveLimits,
    DriveStatus,
    FirmwareInfo,
    LinkError,
    NakError,
)
from controller.errors import LimitError
from firmware_proto.faults import Reject, fault_names
from firmware_proto.registers import RegisterMap, load_register_map

# pymodbus logs every timeout and refused connection at ERROR level; we raise clear errors
# instead, so keep its records out of the last-resort stderr handler.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "server device failure", 5: "acknowledge", 6: "server device busy",
                   8: "memory parity error", 10: "gateway path unavailable",
                   11: "gateway target failed to respond"}
# Modbus exception code -> the closest rejection code of our serial protocol.
_EXCEPTION_REJECT = {1: Reject.UNKNOWN_COMMAND, 2: Reject.BAD_ADDRESS, 3: Reject.OUT_OF_RANGE,
                     4: Reject.FAULT_ACTIVE, 6: Reject.BUSY}
_RETRY_PAUSE_S = 0.05  # before re-sending after a refused/broken connection
_FUNCTION = {3: "read holding", 4: "read input", 6: "write holding", 16: "write holding"}


class ModbusExceptionError(NakError):
    """The device answered with a Modbus exception response."""

    def __init__(self, message: str, code: int, *, unit: int, function_code: int, address: int,
                 exception_code: int) -> None:
        super().__init__(message, code)
        self.unit = unit
        self.function_code = function_code
        self.address = address
        self.exception_code = exception_code


class ModbusLimitError(ModbusExceptionError, LimitError):
    """The device refused a value as out of range (exception 3 on a setpoint, or a command
    the firmware rejected with OUT_OF_RANGE/BAD_LIMITS). Exit status 2, as on the serial link."""


def _exception_error(message: str, code: int, **where) -> ModbusExceptionError:
    limit = code in (Reject.OUT_OF_RANGE, Reject.BAD_LIMITS)
    return (ModbusLimitError if limit else ModbusExceptionError)(message, code, **where)


class ModbusLink:
    """One Modbus connection (TCP) or serial port (RTU) shared by the units on it.

    Use :meth:`tcp` or :meth:`rtu`. ``retries`` is the number of re-sends after a request
    got no answer within ``timeout_s``; ``retries_used`` counts them over the link's life.
    """

    def __init__(self, client, name: str, timeout_s: float, retries: int,
                 register_map: RegisterMap | None = None) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self._client = client
        self.name = name
        self.timeout_s = timeout_s
        self.retries = retries
        self.retries_used = 0
        self.map = register_map or load_register_map()
        self.lock = threading.RLock()

    @classmethod
    def tcp(cls, host: str, port: int, timeout_s: float = 0.3, retries: int = 1) -> ModbusLink:
        """Modbus TCP to ``host:port``. Connects lazily, on the first request."""
        # pymodbus' own retries are off: ours close the connection first and are counted.
        client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
        return cls(client, f"modbus-tcp {host}:{port}", timeout_s, retries)

    @classmethod
    def rtu(cls, device: str, baud: int = 115200, timeout_s: float = 0.3,
            retries: int = 1) -> ModbusLink:
        """Modbus RTU on serial ``device`` (8N1). Opens the port lazily, on the first request."""
        client = ModbusSerialClient(device, baudrate=baud, timeout=timeout_s, retries=0)
        return cls(client, f"modbus-rtu {device}", timeout_s, retries)

    def _describe(self, fc: int, address: int, count: int) -> str:
        table = "input" if fc == 4 else "holding"
        names = []
        for a in range(address, address + count):
            reg = self.map.at(table, a)
            if reg is not None and reg.name not in names:
                names.append(reg.name)
        span = f"{address}" if count == 1 else f"{address}-{address + count - 1}"
        what = names[0] if len(names) == 1 else f"{names[0]}..{names[-1]}" if names else "?"
        return f"{_FUNCTION.get(fc, f'function {fc}')} register {span} ({what})"

    def request(self, unit: int, fc: int, address: int, count: int,
                call: Callable[[object], object], *, retries: int | None = None):
        """Run one pymodbus call with retries; returns (response, retries needed).

        Raises :class:`LinkError` when nothing answered and :class:`ModbusExceptionError`
        on an exception response."""
        attempts = 1 + (self.retries if retries is None else retries)
        last: Exception | None = None
        with self.lock:
            for attempt in range(attempts):
                if attempt:
                    self.retries_used += 1
                try:
                    rr = call(self._client)
                except (ConnectionException, ModbusIOException, OSError) as exc:
                    last = exc
                    # Drop the connection: the next attempt reconnects, and a late answer to
                    # this request cannot be mistaken for the answer to the next one.
                    self._client.close()
                    if isinstance(exc, ConnectionException) and attempt + 1 < attempts:
                        time.sleep(_RETRY_PAUSE_S)
                    continue
                if rr.isError():
                    code = int(getattr(rr, "exception_code", 0) or 0)
                    raise _exception_error(
                        f"{self.name} unit {unit}: {self._describe(fc, address, count)} refused "
                        f"with Modbus exception {code} ({EXCEPTION_NAMES.get(code, 'unknown')})",
                        int(_EXCEPTION_REJECT.get(code, Reject.BAD_LENGTH)), unit=unit,
                        function_code=fc, address=address, exception_code=code)
                return rr, attempt
        if isinstance(last, ModbusIOException):
            reason = "no response"
        elif "Failed to connect" in str(last):
            reason = "cannot connect"
        else:
            reason = str(last).removeprefix("Modbus Error: ").strip()
        raise LinkError(f"{self.name} unit {unit}: no answer to {self._describe(fc, address, count)} "
                        f"after {attempts} attempt(s), timeout {self.timeout_s:g} s: {reason}")

    def read(self, unit: int, table: str, address: int, count: int,
             *, retries: int | None = None) -> tuple[list[int], int]:
        """Read ``count`` registers of ``table`` ("input"/"holding"); returns (words, retries)."""
        if table == "input":
            rr, n = self.request(unit, 4, address, count, lambda c: c.read_input_registers(
                address, count=count, device_id=unit), retries=retries)
        else:
            rr, n = self.request(unit, 3, address, count, lambda c: c.read_holding_registers(
                address, count=count, device_id=unit), retries=retries)
        if len(rr.registers) != count:
            raise DriveError(f"{self.name} unit {unit}: asked for {count} registers at {address}, "
                             f"got {len(rr.registers)}")
        return list(rr.registers), n

    def write(self, unit: int, address: int, words: list[int], *, retries: int | None = None) -> int:
        """Write holding registers (FC 6 for one word, FC 16 otherwise); returns retries."""
        if len(words) == 1:
            _, n = self.request(unit, 6, address, 1, lambda c: c.write_register(
                address, words[0], device_id=unit), retries=retries)
        else:
            _, n = self.request(unit, 16, address, len(words), lambda c: c.write_registers(
                address, words, device_id=unit), retries=retries)
        return n

    def close(self) -> None:
        with self.lock:
            self._client.close()


class ModbusDrive(Drive):
    """A heliostat drive controller at Modbus unit ``unit`` on ``link``."""

    def __init__(self, link: ModbusLink, unit: int, limits: DriveLimits) -> None:
        if not 1 <= unit <= 247:
            raise ValueError(f"Modbus unit ids are 1..247, got {unit}")
        self.link = link
        self.unit = unit
        self.limits = limits
        self.retries_used = 0
        self.map = link.map
        self.last_targets: tuple[int, int] | None = None  # after move/jog, as the device took them

    def _read(self, table: str, first: str, last: str) -> dict[str, int]:
        address, count = self.map.span(first, last)
        words, n = self.link.read(self.unit, table, address, count)
        self.retries_used += n
        return self.map.decode(table, address, words)

    # -- readings ---------------------------------------------------------------------------
    def status(self) -> DriveStatus:
        v = self._read("input", "az_actual_steps", "command_counter")
        bits = v["status_bits"]
        return DriveStatus(
            unit=self.unit, az_steps=v["az_actual_steps"], el_steps=v["el_actual_steps"],
            az_target=v["az_active_target_steps"], el_target=v["el_active_target_steps"],
            moving=bool(bits & self.map.bit("status_bits", "moving")),
            in_position=bool(bits & self.map.bit("status_bits", "in_position")),
            limit_az=bool(bits & self.map.bit("status_bits", "limit_az")),
            limit_el=bool(bits & self.map.bit("status_bits", "limit_el")),
            faults=tuple(fault_names(v["fault_code"])))

    def info(self) -> FirmwareInfo:
        """Firmware identification, as :meth:`SerialDrive.info` gives it: ``protocol_version``
        is the register-map version, ``firmware_version`` "major.minor.patch"."""
        v = self._read("input", "device_type", "el_hard_max_steps")
        if v["device_type"] != self.map.device_type:
            raise DriveError(f"{self.link.name} unit {self.unit}: device type 0x{v['device_type']:04X} "
                             f"is not a heliocal drive controller (0x{self.map.device_type:04X})")
        return FirmwareInfo(
            protocol_version=v["map_version"], axes=2,
            hard_limits=DriveLimits(AxisLimits(v["az_hard_min_steps"], v["az_hard_max_steps"]),
                                    AxisLimits(v["el_hard_min_steps"], v["el_hard_max_steps"])),
            firmware_version=f"{v['fw_version_major']}.{v['fw_version_minor']}.{v['fw_version_patch']}")

    def get_limits(self) -> DriveLimits:
        """The soft limits the device itself enforces (to compare with the configuration)."""
        v = self._read("holding", "az_soft_min_steps", "el_soft_max_steps")
        return DriveLimits(AxisLimits(v["az_soft_min_steps"], v["az_soft_max_steps"]),
                           AxisLimits(v["el_soft_min_steps"], v["el_soft_max_steps"]))

    def set_limits(self, limits: DriveLimits) -> None:
        """Set the device's soft limits (one write, read back). Refused with
        :class:`ModbusLimitError` outside the hard range, exception 6 while moving."""
        with self.link.lock:
            self._write_verified({
                "az_soft_min_steps": limits.az.min_steps, "az_soft_max_steps": limits.az.max_steps,
                "el_soft_min_steps": limits.el.min_steps, "el_soft_max_steps": limits.el.max_steps})

    # -- commands ---------------------------------------------------------------------------
    def _write_verified(self, values: dict[str, int]) -> None:
        """Write setpoint registers, read them back, compare."""
        try:
            address, words = self.map.encode(values)
        except ValueError as exc:
            raise DriveError(f"unit {self.unit}: {exc}; nothing was sent") from None
        self.retries_used += self.link.write(self.unit, address, words)
        back, n = self.link.read(self.unit, "holding", address, len(words))
        self.retries_used += n
        if back != words:
            got = self.map.decode("holding", address, back)
            raise DriveError(f"{self.link.name} unit {self.unit}: read-back mismatch after writing "
                             f"{values}: device holds {got}; no command was sent")

    def _command(self, name: str) -> None:
        """Write the command register once, without blind re-sends: if the answer is lost,
        the device's command counter tells whether the command was executed."""
        reg = self.map["command"]
        code = self.map.code("command", name)
        counter = self.map["command_counter"]
        with self.link.lock:
            before = self._read("input", "command_counter", "command_counter")["command_counter"]
            for attempt in range(1 + self.link.retries):
                try:
                    self.link.write(self.unit, reg.address, reg.encode(code), retries=0)
                    return
                except ModbusExceptionError as exc:
                    raise self._refused(name, exc) from None
                except LinkError:
                    if attempt == self.link.retries:
                        raise
                self.retries_used += 1
                self.link.retries_used += 1
                now = self._read("input", "command_counter", "command_counter")["command_counter"]
                if now == (before + 1) & (counter.limits()[1]):
                    return  # executed; only the answer was lost

    def _refused(self, name: str, exc: ModbusExceptionError) -> ModbusExceptionError:
        """Name the firmware's reason (``last_reject``) in the error of a refused command."""
        try:
            reject = Reject(self._read("input", "last_reject", "last_reject")["last_reject"])
        except (DriveError, ValueError):
            return exc
        return _exception_error(
            f"{exc} -- {name.upper()} rejected by the firmware: {reject.name}", int(reject),
            unit=exc.unit, function_code=exc.function_code, address=exc.address,
            exception_code=exc.exception_code)

    def _send_move_abs(self, az_steps: int, el_steps: int) -> None:
        with self.link.lock:
            self._write_verified({"az_target_steps": az_steps, "el_target_steps": el_steps})
            self._command("move")
        self.last_targets = (az_steps, el_steps)

    def _send_jog(self, daz_steps: int, del_steps: int) -> None:
        with self.link.lock:
            self._write_verified({"jog_az_steps": daz_steps, "jog_el_steps": del_steps})
            self._command("jog")
            v = self._read("input", "az_active_target_steps", "el_active_target_steps")
        self.last_targets = (v["az_active_target_steps"], v["el_active_target_steps"])

    def stop(self) -> None:
        self._command("stop")

    def home(self) -> None:
        self._command("home")

    def stow(self) -> None:
        self._command("stow")

    def clear_fault(self) -> None:
        self._command("clear_fault")

    def close(self) -> None:
        """Drives share their link; closing one drive leaves the link to its owner (LinkPool)."""
