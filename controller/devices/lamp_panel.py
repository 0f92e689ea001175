"""The lamp panel: the field's calibration lamps and the targets' fiducial lamps as a device
(docs/lamps.md).

Each lamp is a *channel* of the configuration's ``lamps:`` section (a lamp id, or
``fiducials:<target id>``). A panel can switch a channel (:meth:`LampPanel.switch`, no wait)
and read whether it is lit now (:meth:`LampPanel.confirmed`: on a Modbus panel the discrete
input wired to the lamp's own sensor, not the coil the controller wrote). The controller never
measures under a lamp it has not seen confirmed: :func:`set_and_confirm`, :func:`light_only`
and :func:`lights_out` switch and then poll the confirmation on plant time, and stop with
:class:`LampNotConfirmed` naming the channel when it does not follow within the timeout.

Drivers: :mod:`controller.devices.lamp_modbus` (Modbus TCP / RTU: coil N switches channel N,
discrete input N confirms it) and :mod:`controller.devices.lamp_command` (the plant's own
switch program); :mod:`controller.devices.lamp_drivers` opens the one the configuration
names (and the fiducial lamps' switch).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from controller.devices.plant_time import PlantTime
from controller.errors import DeviceError, InputError
from controller.lamp_config import FIDUCIALS


class LampError(DeviceError):
    """The lamp panel failed: no answer, a refused request, a failing switch program."""


class LampNotConfirmed(LampError):
    """A lamp did not confirm the state it was switched to within the timeout."""

    def __init__(self, channels: Iterable[str], on: bool, timeout_s: float) -> None:
        self.channels = tuple(channels)
        self.on = on
        names = ", ".join(self.channels)
        super().__init__(f"lamp{'s' if len(self.channels) > 1 else ''} {names} did not confirm "
                         f"{'lit' if on else 'dark'} within {timeout_s:g} s")


@dataclass(frozen=True)
class LampState:
    """One channel now: ``commanded`` what the panel was last told (its coil; None where the
    driver cannot tell), ``lit`` what the lamp confirms."""

    channel: str
    commanded: bool | None
    lit: bool

    def to_json(self) -> dict:
        return {"channel": self.channel, "commanded": self.commanded, "lit": self.lit}


class LampPanel(ABC):
    """A lamp panel; ``channels`` are the configured channel names, in configuration order.
    Close it (or use it as a context manager) to release its connection."""

    channels: tuple[str, ...]
    name: str  # how messages name the panel

    def check_channel(self, channel: str) -> str:
        """``channel`` if it is configured; InputError naming it and the known ones otherwise
        (nothing is sent)."""
        if channel not in self.channels:
            raise InputError(f"no lamp channel {channel!r} in lamps.channels "
                             f"(known: {', '.join(self.channels)})")
        return channel

    @abstractmethod
    def switch(self, channel: str, on: bool) -> None:
        """Command ``channel`` on or off; does not wait for the confirmation."""

    @abstractmethod
    def confirmed(self, channel: str) -> bool:
        """Whether ``channel`` confirms it is lit, now."""

    @abstractmethod
    def states(self) -> list[LampState]:
        """Every channel's commanded and confirmed state."""

    def all_off(self) -> None:
        """Command every channel off (no wait)."""
        for channel in self.channels:
            self.switch(channel, False)

    @abstractmethod
    def close(self) -> None:
        """Release the connection (idempotent)."""

    def __enter__(self) -> LampPanel:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _confirm(panel: LampPanel, channels: list[str], on: bool, time: PlantTime, timeout_s: float) -> None:
    if not time.wait_until(lambda: all(panel.confirmed(c) == on for c in channels), timeout_s):
        raise LampNotConfirmed([c for c in channels if panel.confirmed(c) != on], on, timeout_s)


def set_and_confirm(panel: LampPanel, channel: str, on: bool, *, time: PlantTime, timeout_s: float) -> None:
    """Switch ``channel`` and poll its confirmation every ``time.poll_s`` until it reads ``on``;
    :class:`LampNotConfirmed` after ``timeout_s`` plant seconds."""
    panel.switch(panel.check_channel(channel), on)
    _confirm(panel, [channel], on, time, timeout_s)


def light_only(panel: LampPanel, channel: str, *, time: PlantTime, timeout_s: float) -> None:
    """Every other lamp off and confirmed dark, then ``channel`` on and confirmed lit. Fiducial
    channels are left alone (registration switches them, and leaves them off)."""
    panel.check_channel(channel)
    others = [c for c in panel.channels if c != channel and not c.startswith(FIDUCIALS)]
    for c in others:
        panel.switch(c, False)
    _confirm(panel, others, False, time, timeout_s)
    set_and_confirm(panel, channel, True, time=time, timeout_s=timeout_s)


def lights_out(panel: LampPanel, *, time: PlantTime, timeout_s: float) -> None:
    """Every channel (fiducials too) off and confirmed dark."""
    panel.all_off()
    _confirm(panel, list(panel.channels), False, time, timeout_s)


def fiducials_wired(cfg) -> bool:
    """Whether the plant switches ``cfg``'s calibration target's fiducial lamps itself (a lamp
    panel channel or ``camera.registration.lamp_command``), so a live camera can register."""
    reg = cfg.camera.registration
    return (cfg.lamps is not None and FIDUCIALS + cfg.calibration.target in cfg.lamps.channels) \
        or (reg is not None and bool(reg.lamp_command))


def _plant_switches_them(on: bool) -> None:
    """The registration's fiducial hook where the plant switches the fiducials itself."""


def fiducial_hook(cfg) -> Callable[[bool], None] | None:
    """What a live camera's registration is handed for the fiducial lamps of ``cfg``'s
    calibration target: a hook that leaves the switching to the plant
    (:func:`fiducial_switch` uses its panel channel or lamp command) when :func:`fiducials_wired`,
    else None (nobody can switch them: the camera is not registered)."""
    return _plant_switches_them if fiducials_wired(cfg) else None
