"""Fault bits and rejection codes shared by the firmware, both wire protocols and the drivers.

The fault register is a 16-bit field; each bit below is latched by the firmware until a
CLEAR_FAULT command. Rejection codes say why a command was refused without being executed.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class Fault(IntFlag):
    """Latched fault bits (16-bit). Names are what drivers report in ``faults`` lists."""

    NONE = 0
    STALL_AZ = 0x0001
    STALL_EL = 0x0002
    LIMIT_AZ = 0x0004  # hard limit switch hit on azimuth
    LIMIT_EL = 0x0008
    POWER_CYCLE = 0x0010  # controller restarted since the last CLEAR_FAULT
    OVERCURRENT = 0x0020


def fault_names(bits: int) -> list[str]:
    """Names of the set bits, lower-case, in bit order (e.g. ``["stall_az", "power_cycle"]``)."""
    return [f.name.lower() for f in Fault if f and bits & f]


class Reject(IntEnum):
    """Why a command was refused. Numeric values are the serial NAK codes (PROTOCOL.md)."""

    OK = 0x00
    UNKNOWN_COMMAND = 0x01
    BAD_LENGTH = 0x02
    OUT_OF_RANGE = 0x03  # target outside the soft limits
    FAULT_ACTIVE = 0x04  # a latched fault blocks motion until CLEAR_FAULT
    BUSY = 0x05  # e.g. HOME in progress
    BAD_LIMITS = 0x06  # SET_LIMITS outside the hard range, min >= max, or excluding position/target
    BAD_ADDRESS = 0x07
    INTERNAL = 0x08  # the firmware could not execute the command (it stays up and answers)
