"""Open drives from configuration links, sharing each physical link between its units.

Several heliostat controllers share one RS-485 bus (serial) or one Modbus TCP gateway, so
a :class:`LinkPool` opens each bus or connection once and hands out one :class:`Drive` per
bus address / unit id. The caller never needs to know which link a heliostat has.
:func:`open_camera` opens the field camera the same way: from the configuration.
"""

from __future__ import annotations

from controller.config import Camera
from controller.devices.camera import DoubleCcdCamera
from controller.devices.drive import Drive, DriveLimits
from controller.link_config import Link, ModbusRtuLink, ModbusTcpLink, NoLink, SerialLink


def open_camera(cfg: Camera, manifest: str | None = None) -> DoubleCcdCamera:
    """The field camera, the one way every command opens it (``campaign run|night``, the
    console, ``commission``, ``capture``): recorded pairs from ``manifest`` when given (a
    command's ``--camera-manifest``), else the driver the configuration names
    (``camera.driver``: ``gige``, the GigE Vision imagers of ``camera.gige``; ``file``, the
    recorded pairs of ``camera.manifest``; docs/camera.md). The simulated plant's cameras are
    the simulator's (``--simulate``). InputError when there is none."""
    if manifest is not None or cfg.driver == "file":
        from controller.devices.file_camera import FileCamera

        return FileCamera(manifest if manifest is not None else cfg.manifest)
    if cfg.driver == "gige":
        from controller.devices.gige import GigeCamera

        return GigeCamera(cfg)
    from controller.errors import InputError

    raise InputError("no camera: the configuration sets no camera.driver (gige: GigE Vision imagers, file: "
                     "recorded pairs; docs/camera.md) and no recorded pairs were given")


class LinkPool:
    """Owns the open buses and connections; close it to release them all."""

    def __init__(self, *, timeout_s: float | None = None, retries: int | None = None) -> None:
        self._timeout = timeout_s
        self._retries = retries
        self._links: dict[tuple, object] = {}

    def _opts(self) -> dict:
        opts = {}
        if self._timeout is not None:
            opts["timeout_s"] = self._timeout
        if self._retries is not None:
            opts["retries"] = self._retries
        return opts

    def drive(self, link: Link, limits: DriveLimits) -> Drive:
        """A drive for ``link``; opens the underlying bus/connection on first use. ConfigError
        for ``link: none`` (a heliostat known by its records only: nothing is sent to it)."""
        if isinstance(link, NoLink):
            from controller.errors import ConfigError

            raise ConfigError("link: none: this heliostat has no link to its drive (records only, e.g. "
                              "imported from PAINT); write its link into the configuration to drive it")
        key = link.bus_key
        if isinstance(link, SerialLink):
            from controller.devices.serial_drive import SerialBus, SerialDrive

            if key not in self._links:
                self._links[key] = SerialBus(link.device, link.baud, **self._opts())
            return SerialDrive(self._links[key], link.address, limits)
        from controller.devices.modbus_drive import ModbusDrive, ModbusLink

        if key not in self._links:
            if isinstance(link, ModbusTcpLink):
                self._links[key] = ModbusLink.tcp(link.host, link.port, **self._opts())
            elif isinstance(link, ModbusRtuLink):
                self._links[key] = ModbusLink.rtu(link.device, link.baud, **self._opts())
            else:  # pragma: no cover - pydantic's discriminated union admits nothing else
                raise TypeError(f"unknown link {link!r}")
        return ModbusDrive(self._links[key], link.unit, limits)

    def close(self) -> None:
        for link in self._links.values():
            link.close()
        self._links.clear()

    def __enter__(self) -> LinkPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
