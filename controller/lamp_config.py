"""The ``lamps:`` section of the plant configuration (docs/lamps.md, docs/configuration.md): how
the controller switches the field's calibration lamps and the targets' fiducial lamps, and
reads back that each one is lit or dark. Re-exported by :mod:`controller.config`, whose
:func:`load_config` validates it and cross-checks the channel names against
``light_sources``, ``targets`` and ``calibration``.

One *channel* per lamp: ``channels`` maps a channel name (a lamp id of ``light_sources``, or
``fiducials:<target id>`` for a target's fiducial lamps) to its 0-based index — on a Modbus
panel the coil that switches it and the discrete input that confirms it.
"""

from __future__ import annotations

import ipaddress
import re
from typing import Annotated, Literal

from pydantic import Field, field_validator

from controller.config_rules import Section

FIDUCIALS = "fiducials:"  # channel-name prefix of a target's fiducial lamps
MAX_CHANNELS = 256
MAX_INDEX = 65535  # Modbus coil / discrete-input addresses are 16 bit
_LABEL = re.compile(r"[A-Za-z0-9_]([A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?")  # one label of a host name


Index = Annotated[int, Field(strict=True, ge=0, le=MAX_INDEX)]  # strict: true/false are no index


_Model = Section  # as every configuration section (controller.config_rules)


class _Lamps(_Model):
    channels: dict[str, Index] = Field(min_length=1, max_length=MAX_CHANNELS,
                                     description="channel name -> coil / discrete input index")
    confirm_timeout_s: float = Field(default=10.0, gt=0, le=600,
                                     description="plant seconds a lamp has to confirm its state")

    @field_validator("channels")
    @classmethod
    def _indices(cls, v: dict[str, int]) -> dict[str, int]:
        seen: dict[int, str] = {}
        for name, index in v.items():
            if not name or len(name) > 128:
                raise ValueError(f"{name!r}: a channel name has 1..128 characters")
            if index in seen:
                raise ValueError(f"{name}: index {index} is already the channel of {seen[index]!r}")
            seen[index] = name
        return v


class ModbusTcpLamps(_Lamps):
    """A lamp panel or PLC on Modbus TCP: coil N switches channel N, discrete input N confirms it."""

    driver: Literal["modbus-tcp"]
    host: str = Field(min_length=1, max_length=253)
    port: int = Field(default=502, ge=1, le=65535)
    unit: int = Field(default=1, ge=1, le=247)
    timeout_s: float = Field(default=1.0, gt=0, le=60, description="answer timeout per request, s")

    @field_validator("host")
    @classmethod
    def _host(cls, v: str) -> str:
        try:
            ipaddress.ip_address(v)
            return v
        except ValueError:
            pass
        if not all(_LABEL.fullmatch(label) for label in v.removesuffix(".").split(".")):
            raise ValueError(f"{v[:80]!r} is neither an IP address nor a host name (dot-separated labels "
                             "of 1 to 63 letters, digits, '-' and '_')")
        return v

    @property
    def name(self) -> str:
        return f"lamp panel modbus-tcp {self.host}:{self.port} unit {self.unit}"


class ModbusRtuLamps(_Lamps):
    """The same panel on Modbus RTU (RS-485, 8N1)."""

    driver: Literal["modbus-rtu"]
    device: str = Field(min_length=1, max_length=4096)
    baud: int = Field(default=19200, ge=300, le=4_000_000)
    unit: int = Field(default=1, ge=1, le=247)
    timeout_s: float = Field(default=1.0, gt=0, le=60, description="answer timeout per request, s")

    @property
    def name(self) -> str:
        return f"lamp panel modbus-rtu {self.device} unit {self.unit}"


class CommandLamps(_Lamps):
    """The plant's own switch program: ``command + [on|off, CHANNEL]`` exits 0 once the lamp is
    so; ``command + [status, CHANNEL]`` exits 0 lit, 1 dark."""

    driver: Literal["command"]
    command: tuple[str, ...] = Field(min_length=1, max_length=32)
    timeout_s: float = Field(default=30.0, gt=0, le=600, description="time one run may take, s")

    @field_validator("command")
    @classmethod
    def _program(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        if not v[0]:
            raise ValueError("the program (first element) must not be empty")
        for i, arg in enumerate(v):
            if "\0" in arg:
                raise ValueError(f"element {i} holds a NUL character, which no program argument can")
        return v

    @property
    def name(self) -> str:
        return "lamps.command"


Lamps = Annotated[ModbusTcpLamps | ModbusRtuLamps | CommandLamps, Field(discriminator="driver")]


def check_channels(lamps: _Lamps, lamp_ids: set[str], target_ids: set[str], needed: list[str],
                   command_fiducials: set[str]) -> None:
    """Cross-checks with the rest of the configuration (ValueError naming the key): every
    channel is a lamp of ``lamp_ids`` or ``fiducials:`` an id of ``target_ids``; every lamp of
    ``needed`` (the lamps campaigns light) has a channel; no target's fiducials are switched by
    both a channel and ``camera.registration.lamp_command`` (the targets of ``command_fiducials``)."""
    for name in lamps.channels:
        key = f"lamps.channels.{name}"
        if name.startswith(FIDUCIALS):
            target = name.removeprefix(FIDUCIALS)
            if target not in target_ids:
                raise ValueError(f"{key}: {target!r} is not the id of any entry of targets")
            if target in command_fiducials:
                raise ValueError(f"{key}: the fiducial lamps of {target!r} are switched by "
                                 "camera.registration.lamp_command too; configure one of them")
        elif name not in lamp_ids:
            raise ValueError(f"{key}: {name!r} is neither the id of a lamp of light_sources nor "
                             f"{FIDUCIALS}<target id>")
    for lamp in needed:
        if lamp not in lamps.channels:
            raise ValueError(f"lamps.channels: lamp {lamp!r} (calibration.light_source or calibration.lamps) "
                             "has no channel")
