"""In-process drives: the simulated firmware's physics called directly, without a wire.

For fields too large for ptys and sockets (``benchmarks/bench_field.py``): :class:`InProcPool`
stands in for :class:`controller.devices.factory.LinkPool` (the ``pool.drive(link, limits)``
the campaign runner calls) and hands out an :class:`InProcDrive` per heliostat, a
:class:`controller.devices.drive.Drive` whose verbs go straight to the heliostat's
:class:`simplant.firmware.physics.SimController` on the plant clock. What the firmware does
on the wire it does here too: it refuses targets outside its own soft limits, moves while
faults are latched, limits it cannot take, with the same rejection codes (NAK errors,
:func:`controller.devices.serial_drive.nak_error`); only transport errors cannot happen.
"""

from __future__ import annotations

from controller.devices.drive import AxisLimits, Drive, DriveLimits, DriveStatus, FirmwareInfo
from controller.devices.lamp_panel import LampPanel, LampState
from controller.devices.serial_drive import nak_error
from firmware_proto.faults import Reject, fault_names
from firmware_proto.messages import PROTOCOL_VERSION, Command
from simplant.firmware.physics import SimController


class InProcDrive(Drive):
    """A :class:`Drive` over one :class:`SimController` (module docstring)."""

    def __init__(self, controller: SimController, limits: DriveLimits, frozen=None, touched=None) -> None:
        self.ctl = controller
        self._frozen = frozen
        self._touched = touched or (lambda: None)
        self.unit = controller.unit
        self.limits = limits
        self.retries_used = 0
        self.last_targets: tuple[int, int] | None = None

    def _ok(self, command: Command, result: Reject) -> None:
        self._touched()  # the rods may move from now on
        if result != Reject.OK:
            raise nak_error(self.unit, command, int(result))

    def status(self) -> DriveStatus:
        if self._frozen is not None:
            with self._frozen():
                s = self.ctl.status()
        else:
            s = self.ctl.status()
        return DriveStatus(self.unit, s["az_steps"], s["el_steps"], s["az_target"], s["el_target"],
                           s["moving"], s["in_position"], s["limit_az"], s["limit_el"],
                           tuple(fault_names(s["faults"])) if s["faults"] else ())

    def info(self) -> FirmwareInfo:
        az, el = self.ctl.az, self.ctl.el
        return FirmwareInfo(PROTOCOL_VERSION, 2, DriveLimits(AxisLimits(az.hard_min, az.hard_max),
                                                             AxisLimits(el.hard_min, el.hard_max)),
                            self.ctl.firmware_version)

    def get_limits(self) -> DriveLimits:
        az, el = self.ctl.az, self.ctl.el
        return DriveLimits(AxisLimits(az.soft_min, az.soft_max), AxisLimits(el.soft_min, el.soft_max))

    def set_limits(self, limits: DriveLimits) -> None:
        self._ok(Command.SET_LIMITS, self.ctl.set_limits(limits.az.min_steps, limits.az.max_steps,
                                                         limits.el.min_steps, limits.el.max_steps))

    def _send_move_abs(self, az_steps: int, el_steps: int) -> None:
        self._ok(Command.MOVE_ABS, self.ctl.move_abs(int(az_steps), int(el_steps)))
        self.last_targets = (int(az_steps), int(el_steps))

    def _send_jog(self, daz_steps: int, del_steps: int) -> None:
        self._ok(Command.JOG, self.ctl.jog(int(daz_steps), int(del_steps)))
        s = self.ctl.status()
        self.last_targets = (s["az_target"], s["el_target"])

    def stop(self) -> None:
        self._ok(Command.STOP, self.ctl.stop())

    def home(self) -> None:
        self._ok(Command.HOME, self.ctl.home())

    def stow(self) -> None:
        self._ok(Command.STOW, self.ctl.stow())

    def clear_fault(self) -> None:
        self._ok(Command.CLEAR_FAULT, self.ctl.clear_fault())

    def close(self) -> None:
        """Nothing to release."""


class InProcPool:
    """``drive(link, limits)`` as :class:`LinkPool` has it, over ``controllers`` keyed by the
    link's bus and station (``(*link.bus_key, link.station)``, see :meth:`key`).

    ``frozen``: a context manager that stops the plant clock (``PlantClock.frozen``) around
    each status reading. With a large clock speedup the simulator's own cost of integrating
    the motion (tens of µs of wall time per poll) would otherwise cost the plant a sizeable
    fraction of every poll interval; a real status poll takes milliseconds.

    ``touched(hid)``: told of every command a heliostat's drive is sent
    (:meth:`simplant.devices.cheap_camera.BeamField.touch`); ``ids`` names the heliostat of each key."""

    def __init__(self, controllers: dict[tuple, SimController], frozen=None, touched=None,
                 ids: dict[tuple, str] | None = None) -> None:
        self._ctl = dict(controllers)
        self._frozen = frozen
        self._touched = touched
        self._ids = ids or {}

    @staticmethod
    def key(link) -> tuple:
        return (*link.bus_key, link.station)

    @classmethod
    def for_plant(cls, plant, touched=None) -> InProcPool:
        """The drives of every hidden heliostat of a :class:`simplant.plant.SimulatedPlant`
        (not started: its links stay as configured)."""
        cfg = plant.cfg
        keys = {hid: cls.key(cfg.heliostat(hid).link) for hid in plant.hidden}
        return cls({keys[hid]: hh.controller for hid, hh in plant.hidden.items()}, plant.clock.frozen,
                   touched, {k: hid for hid, k in keys.items()})

    def drive(self, link, limits: DriveLimits) -> InProcDrive:
        try:
            ctl = self._ctl[self.key(link)]
        except KeyError:
            raise nak_error(link.station, Command.GET_STATUS, int(Reject.BAD_ADDRESS)) from None
        hid = self._ids.get(self.key(link))
        touched = (lambda: self._touched(hid)) if self._touched is not None and hid is not None else None
        return InProcDrive(ctl, limits, self._frozen, touched)

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> InProcPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class InProcLampPanel(LampPanel):
    """The plant's lamps as a :class:`controller.devices.lamp_panel.LampPanel` without a wire
    (a field too large for sockets): a switch is the plant's lamp at once, and the lamp
    confirms what it actually is (every lamp of ``light_sources`` is a channel)."""

    name = "in-process lamp panel"

    def __init__(self, plant) -> None:
        self.plant = plant
        self.channels = tuple(s.id for s in plant.cfg.light_sources if s.kind == "lamp")

    def switch(self, channel: str, on: bool) -> None:
        self.plant.switch_lamp(self.check_channel(channel), on)

    def confirmed(self, channel: str) -> bool:
        return self.plant.lamp_lit(self.check_channel(channel))

    def states(self) -> list[LampState]:
        return [LampState(c, self.plant.lamp_lit(c), self.plant.lamp_lit(c)) for c in self.channels]

    def close(self) -> None:
        """Nothing to release."""
