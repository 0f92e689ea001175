"""Commands and payload layouts of the serial actuator protocol (PROTOCOL.md, "Commands").

All integers are little-endian; steps are signed 32-bit. A reply carries the request's
command with bit 7 set (:data:`REPLY_BIT`) and starts with one status byte: 0 is ACK (the
data follows), any other value is a NAK whose code is a :class:`firmware_proto.faults.Reject`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from firmware_proto.faults import Reject

PROTOCOL_VERSION = 1
REPLY_BIT = 0x80
BROADCAST = 0  # reserved; firmware never answers address 0
MAX_PING = 16  # PING echoes up to this many payload bytes
VERSION_LEN = 16  # firmware version string in GET_INFO, ASCII, at most this long


class Command(IntEnum):
    PING = 0x01
    GET_INFO = 0x02
    GET_STATUS = 0x03
    MOVE_ABS = 0x10
    JOG = 0x11
    STOP = 0x12
    HOME = 0x13
    STOW = 0x14
    GET_LIMITS = 0x20
    SET_LIMITS = 0x21
    CLEAR_FAULT = 0x30


# Request payload length of each command (PING: 0..MAX_PING bytes).
REQUEST_LENGTH = {
    Command.GET_INFO: 0, Command.GET_STATUS: 0, Command.MOVE_ABS: 8, Command.JOG: 8,
    Command.STOP: 0, Command.HOME: 0, Command.STOW: 0, Command.GET_LIMITS: 0,
    Command.SET_LIMITS: 16, Command.CLEAR_FAULT: 0,
}

PAIR = struct.Struct("<ii")  # MOVE_ABS/JOG request (az, el); JOG ACK: new targets
LIMITS = struct.Struct("<iiii")  # az_min, az_max, el_min, el_max
STATUS = struct.Struct("<iiiiBH")  # az actual, az target, el actual, el target, flags, faults
INFO = struct.Struct("<BBiiii")  # protocol version, axes, az hard min/max, el hard min/max

FLAG_MOVING = 0x01
FLAG_IN_POSITION = 0x02
FLAG_LIMIT_AZ = 0x04
FLAG_LIMIT_EL = 0x08


@dataclass(frozen=True)
class Status:
    """GET_STATUS data, steps; ``faults`` is the latched :class:`~firmware_proto.faults.Fault` bits."""

    az_steps: int
    az_target: int
    el_steps: int
    el_target: int
    moving: bool
    in_position: bool
    limit_az: bool
    limit_el: bool
    faults: int

    def pack(self) -> bytes:
        flags = ((FLAG_MOVING if self.moving else 0) | (FLAG_IN_POSITION if self.in_position else 0)
                 | (FLAG_LIMIT_AZ if self.limit_az else 0) | (FLAG_LIMIT_EL if self.limit_el else 0))
        return STATUS.pack(self.az_steps, self.az_target, self.el_steps, self.el_target, flags,
                           self.faults)

    @classmethod
    def unpack(cls, data: bytes) -> Status:
        az, az_t, el, el_t, flags, faults = STATUS.unpack(data)
        return cls(az, az_t, el, el_t, bool(flags & FLAG_MOVING), bool(flags & FLAG_IN_POSITION),
                   bool(flags & FLAG_LIMIT_AZ), bool(flags & FLAG_LIMIT_EL), faults)


@dataclass(frozen=True)
class Info:
    """GET_INFO data: protocol version, number of axes, hard step ranges, firmware version."""

    protocol_version: int
    axes: int
    az_hard_min: int
    az_hard_max: int
    el_hard_min: int
    el_hard_max: int
    firmware_version: str

    def pack(self) -> bytes:
        return INFO.pack(self.protocol_version, self.axes, self.az_hard_min, self.az_hard_max,
                         self.el_hard_min, self.el_hard_max) + \
            self.firmware_version.encode("ascii", "replace")[:VERSION_LEN]

    @classmethod
    def unpack(cls, data: bytes) -> Info:
        head = INFO.unpack(data[:INFO.size])
        return cls(*head, data[INFO.size:].decode("ascii", "replace"))


def ack(data: bytes = b"") -> bytes:
    """Reply payload of an executed command."""
    return bytes((Reject.OK,)) + data


def nak(code: Reject) -> bytes:
    """Reply payload of a refused command."""
    return bytes((int(code),))
