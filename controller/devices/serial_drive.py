"""Serial drive: our frame protocol (firmware_proto/PROTOCOL.md) over an RS-485 port, pyserial.

:class:`SerialBus` owns one physical port shared by several controllers (multi-drop). Each
request is a transaction under the bus lock: write the frame, collect bytes until a valid
reply with the same address and sequence number arrives or the monotonic deadline passes
(pyserial's ``inter_byte_timeout`` does nothing on Linux, so timing is ours), and on timeout
retransmit the *same* frame, same sequence number, so the firmware answers a duplicate
from its last reply instead of executing it twice. Garbage is skipped by the codec's
streaming decoder, which resynchronises at the next frame delimiter.

:class:`SerialDrive` turns replies into :class:`~controller.devices.drive.Drive` verbs and
NAK codes into exceptions (:func:`nak_error`).
"""

from __future__ import annotations

import os
import select
import termios
import threading
import time

import serial

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
from firmware_proto.codec import Decoder, Frame, encode
from firmware_proto.faults import Reject, fault_names
from firmware_proto.messages import LIMITS, PAIR, REPLY_BIT, Command, Info, Status


class FirmwareLimitError(NakError, LimitError):
    """The firmware refused a target or limits as out of range (NAK OUT_OF_RANGE/BAD_LIMITS).
    Exit status 2 like the controller's own :class:`LimitError`."""


_NAK_TEXT = {
    Reject.UNKNOWN_COMMAND: "the firmware does not know this command (older firmware?)",
    Reject.BAD_LENGTH: "the firmware rejected the payload length (protocol version mismatch?)",
    Reject.OUT_OF_RANGE: "the target is outside the firmware's soft limits",
    Reject.FAULT_ACTIVE: "a latched fault blocks motion; read the status and send CLEAR_FAULT",
    Reject.BUSY: "the controller is busy",
    Reject.BAD_LIMITS: "the limits are outside the hard range or min >= max",
    Reject.BAD_ADDRESS: "bad address",
}


def nak_error(unit: int, command: int, code: int) -> NakError:
    """The exception for a NAK ``code`` to ``command`` from ``unit``."""
    try:
        name = Command(command).name
    except ValueError:
        name = f"command 0x{command:02X}"
    try:
        reject = Reject(code)
        text = f"NAK {reject.name} (0x{code:02X}): {_NAK_TEXT.get(reject, reject.name)}"
    except ValueError:
        reject = None
        text = f"NAK with unknown code 0x{code:02X}"
    message = f"unit {unit} refused {name}: {text}"
    if reject in (Reject.OUT_OF_RANGE, Reject.BAD_LIMITS):
        return FirmwareLimitError(message, code)
    return NakError(message, code)


class SerialBus:
    """One serial port shared by the controllers on it; thread-safe.

    ``timeout_s`` is the reply deadline of one attempt, ``retries`` the retransmissions after
    the first attempt. Counters: ``retries_used``, ``stale_frames`` (valid frames that were
    not the awaited reply) and ``garbage`` (rejected chunks by reason, from the decoder).
    """

    def __init__(self, device: str, baud: int = 115200, timeout_s: float = 0.2, retries: int = 3) -> None:
        if timeout_s <= 0 or retries < 0:
            raise ValueError("timeout_s must be > 0 and retries >= 0")
        self.device = device
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        # One character time of silence after a reply before we transmit (PROTOCOL.md, "Timing").
        self.gap_s = 10.0 / baud
        self.baud = baud
        self._ser: serial.Serial | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._decoder = Decoder()
        self._seq: dict[int, int] = {}
        self._last_rx = 0.0
        self._open()
        self.retries_used = 0
        self.stale_frames = 0

    def _open(self) -> None:
        """Open the port by name (a re-created symlink leads to the new pty). A new session:
        sequence numbers restart with a session-start PING per address."""
        try:
            self._ser = serial.Serial(self.device, self.baud, timeout=0, write_timeout=1.0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open serial device {self.device}: {exc}", "not_executed") from None
        self._fd = self._ser.fileno()
        self._seq.clear()
        self._decoder.reset()

    def _drop_port(self) -> None:
        try:
            self._ser.close()
        except (serial.SerialException, OSError, termios.error):
            pass  # the port is already gone; closing is best effort
        self._ser = None

    @property
    def garbage(self) -> dict[str, int]:
        return dict(self._decoder.counts)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            if self._ser is not None:
                self._drop_port()

    def __enter__(self) -> SerialBus:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def request(self, address: int, command: int, payload: bytes = b"") -> tuple[Frame, int]:
        """Send one request and return ``(reply frame, retransmissions needed)``.

        The first request to an address after opening the bus is preceded by a PING with a
        random nonce, so the firmware's duplicate cache can never match a request from an
        earlier session (PROTOCOL.md, "Session start"). Raises :class:`LinkError`. After the
        port was lost (device gone, EIO) the next request reopens it by name.
        """
        with self._lock:
            if self._closed:
                raise LinkError(f"serial bus {self.device} is closed", "not_executed")
            if self._ser is None:
                self._open()
            retries = 0
            try:
                if address not in self._seq:
                    seq = int.from_bytes(os.urandom(1), "little")
                    _, retries = self._transact(address, seq, Command.PING, os.urandom(8))
                    self._seq[address] = (seq + 1) & 0xFF
                seq = self._seq[address]
                self._seq[address] = (seq + 1) & 0xFF
                reply, more = self._transact(address, seq, command, payload)
            except LinkError:
                # After any link error the session starts anew (a fresh PING nonce): during a
                # long outage the 8-bit sequence wraps, and a later request with the same bytes
                # as the last one executed would otherwise be answered from the firmware's
                # duplicate cache without being executed.
                self._seq.pop(address, None)
                raise
            return reply, retries + more

    def _transact(self, address: int, seq: int, command: int, payload: bytes) -> tuple[Frame, int]:
        wire = encode(Frame(address, seq, command, payload))
        want = command | REPLY_BIT
        for attempt in range(self.retries + 1):
            if attempt:
                self.retries_used += 1
            try:
                # Stale bytes (late replies to an earlier attempt, garbage) need no flush: the
                # decoder drops garbage and replies with another sequence number are ignored.
                while time.monotonic() < self._last_rx + self.gap_s:
                    pass  # inter-frame gap: at most one character time (~87 us at 115200 baud)
                self._write(wire)
                reply = self._await(address, seq, want, time.monotonic() + self.timeout_s)
            except (serial.SerialException, OSError, termios.error) as exc:
                # A pty whose firmware went away reports EIO; reopen on the next request.
                self._drop_port()
                raise LinkError(f"serial link {self.device} lost: {exc}") from None
            if reply is not None:
                return reply, attempt
        try:
            name = Command(command).name
        except ValueError:
            name = f"0x{command:02X}"
        raise LinkError(f"unit {address}: no valid reply to {name} on {self.device} after "
                        f"{self.retries + 1} attempts of {self.timeout_s:g} s")

    def _write(self, wire: bytes) -> None:
        """Write all of ``wire`` to the (non-blocking) port fd, waiting at most 1 s for room.
        Straight to the fd: pyserial's write adds a select per call (~20 us)."""
        deadline = time.monotonic() + 1.0
        view = memoryview(wire)
        while view:
            try:
                view = view[os.write(self._fd, view):]
            except BlockingIOError:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise serial.SerialTimeoutException("write timeout (1 s)") from None
                select.select([], [self._fd], [], remaining)

    def _await(self, address: int, seq: int, want: int, deadline: float) -> Frame | None:
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            ready, _, _ = select.select([self._fd], [], [], remaining)
            if not ready:
                return None
            # pyserial opened and configured the port; reading the ready fd directly saves
            # pyserial's second select per chunk (the exchange budget is ~0.5 ms).
            try:
                data = os.read(self._fd, 4096)
            except BlockingIOError:
                continue  # spurious readiness
            if not data:
                raise serial.SerialException("device reports readiness to read but returned no data")
            for frame in self._decoder.feed(data):
                if frame.address == address and frame.seq == seq and frame.command == want \
                        and frame.payload:
                    self._last_rx = time.monotonic()
                    return frame
                self.stale_frames += 1


class SerialDrive(Drive):
    """The :class:`Drive` of the controller at bus ``address`` on ``bus``.

    ``retries_used`` counts retransmissions of this drive's requests. ``close()`` leaves the
    shared bus open (close the bus, or the :class:`~controller.devices.factory.LinkPool`).
    """

    def __init__(self, bus: SerialBus, address: int, limits: DriveLimits) -> None:
        if not 1 <= address <= 247:
            raise ValueError(f"bus address must be 1..247, got {address}")
        self.bus = bus
        self.unit = address
        self.limits = limits
        self.retries_used = 0
        self.last_targets: tuple[int, int] | None = None

    def _call(self, command: Command, payload: bytes = b"") -> bytes:
        frame, retries = self.bus.request(self.unit, command, payload)
        self.retries_used += retries
        if frame.payload[0] != Reject.OK:
            raise nak_error(self.unit, command, frame.payload[0])
        return frame.payload[1:]

    def _data(self, command: Command, size: int, payload: bytes = b"") -> bytes:
        data = self._call(command, payload)
        if len(data) < size:
            raise DriveError(f"unit {self.unit}: {command.name} reply has {len(data)} data bytes, "
                             f"expected {size}")
        return data

    def ping(self, data: bytes = b"") -> bytes:
        return self._call(Command.PING, data)

    def status(self) -> DriveStatus:
        s = Status.unpack(self._data(Command.GET_STATUS, 19)[:19])
        return DriveStatus(self.unit, s.az_steps, s.el_steps, s.az_target, s.el_target, s.moving,
                           s.in_position, s.limit_az, s.limit_el,
                           tuple(fault_names(s.faults)) if s.faults else ())

    def info(self) -> FirmwareInfo:
        i = Info.unpack(self._data(Command.GET_INFO, 18))
        return FirmwareInfo(i.protocol_version, i.axes,
                            DriveLimits(AxisLimits(i.az_hard_min, i.az_hard_max),
                                        AxisLimits(i.el_hard_min, i.el_hard_max)),
                            i.firmware_version)

    def get_limits(self) -> DriveLimits:
        """The soft limits the firmware enforces."""
        az0, az1, el0, el1 = LIMITS.unpack(self._data(Command.GET_LIMITS, LIMITS.size)[:LIMITS.size])
        return DriveLimits(AxisLimits(az0, az1), AxisLimits(el0, el1))

    def set_limits(self, limits: DriveLimits) -> None:
        """Set the firmware's soft limits (refused with FirmwareLimitError outside the hard range)."""
        self._call(Command.SET_LIMITS, LIMITS.pack(limits.az.min_steps, limits.az.max_steps,
                                                   limits.el.min_steps, limits.el.max_steps))

    def _send_move_abs(self, az_steps: int, el_steps: int) -> None:
        self._call(Command.MOVE_ABS, PAIR.pack(az_steps, el_steps))
        self.last_targets = (az_steps, el_steps)

    def _send_jog(self, daz_steps: int, del_steps: int) -> None:
        data = self._data(Command.JOG, PAIR.size, PAIR.pack(daz_steps, del_steps))
        self.last_targets = PAIR.unpack(data[:PAIR.size])

    def stop(self) -> None:
        self._call(Command.STOP)

    def home(self) -> None:
        self._call(Command.HOME)

    def stow(self) -> None:
        self._call(Command.STOW)

    def clear_fault(self) -> None:
        self._call(Command.CLEAR_FAULT)

    def close(self) -> None:
        """Nothing to release: the bus is shared and closed by its owner."""
