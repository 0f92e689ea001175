"""The links of the plant configuration (``heliostats[i].link``, docs/configuration.md): how
the controller reaches each heliostat's drive — our serial frame protocol on an RS-485 bus,
Modbus TCP through a gateway, Modbus RTU, or none (records only) — and the buses of a field
kept in its own file (``field.buses``: the same links without their station). Re-exported by
:mod:`controller.config`, whose :func:`load_config` validates it.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from controller.config_rules import Baud, Section

_Model = Section  # as every configuration section (controller.config_rules)


class SerialLink(_Model):
    kind: Literal["serial"]
    device: str
    address: int = Field(ge=1, le=247)
    baud: Baud = 115200

    @property
    def bus_key(self) -> tuple:
        """The physical link several heliostats share (opened once): the serial bus."""
        return ("serial", self.device)

    @property
    def station(self) -> int:
        """This heliostat's address on its bus."""
        return self.address


class ModbusTcpLink(_Model):
    kind: Literal["modbus-tcp"]
    host: str
    port: int = Field(ge=1, le=65535)
    unit: int = Field(ge=1, le=247)

    @property
    def bus_key(self) -> tuple:
        """The physical link several heliostats share: the gateway's TCP connection."""
        return ("modbus-tcp", self.host, self.port)

    @property
    def station(self) -> int:
        return self.unit


class ModbusRtuLink(_Model):
    kind: Literal["modbus-rtu"]
    device: str
    unit: int = Field(ge=1, le=247)
    baud: Baud = 115200

    @property
    def bus_key(self) -> tuple:
        """The physical link several heliostats share: the RS-485 bus."""
        return ("modbus-rtu", self.device)

    @property
    def station(self) -> int:
        return self.unit


class NoLink(_Model):
    """No link: a heliostat the controller holds records of but cannot reach — a field imported
    from another system's records (``heliocal import paint``, docs/import.md) until its links
    are written in. Nothing can be sent to it: opening its drive is refused
    (:class:`controller.devices.factory.LinkPool`)."""

    kind: Literal["none"]

    @property
    def bus_key(self) -> tuple:
        return ("none",)

    @property
    def station(self) -> int:
        return 0


Link = Annotated[SerialLink | ModbusTcpLink | ModbusRtuLink | NoLink, Field(discriminator="kind")]


# The buses and gateways of ``field.buses`` (docs/configuration.md, "The field in its own
# file"): a link without its station; ``link(station)`` completes it with the field file's
# ``station`` column (a bus address or unit id, 1 … 247).


class SerialBus(_Model):
    kind: Literal["serial"]
    device: str
    baud: Baud = 115200

    def link(self, station: int) -> SerialLink:
        return SerialLink(kind="serial", device=self.device, address=station, baud=self.baud)


class ModbusTcpBus(_Model):
    kind: Literal["modbus-tcp"]
    host: str
    port: int = Field(ge=1, le=65535)

    def link(self, station: int) -> ModbusTcpLink:
        return ModbusTcpLink(kind="modbus-tcp", host=self.host, port=self.port, unit=station)


class ModbusRtuBus(_Model):
    kind: Literal["modbus-rtu"]
    device: str
    baud: Baud = 115200

    def link(self, station: int) -> ModbusRtuLink:
        return ModbusRtuLink(kind="modbus-rtu", device=self.device, unit=station, baud=self.baud)


Bus = Annotated[SerialBus | ModbusTcpBus | ModbusRtuBus, Field(discriminator="kind")]
