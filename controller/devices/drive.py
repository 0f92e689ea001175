"""The drive interface every actuator link implements (serial frame protocol, Modbus).

The calibration state machine talks only to :class:`Drive`, so it does not care which link
a heliostat has. Positions are motor steps (int). Soft limits are checked here, in the
controller, *before* anything is sent; the firmware checks them again.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

from controller.devices.plant_time import PlantTime
from controller.errors import DeviceError, LimitError

# Drive waits poll faster than the default plant time: a move's end is worth catching early.
DRIVE_TIME = PlantTime(poll_s=0.02)
# The longest pause between two status polls of a moving drive, in polling periods: how late a
# stop request or a fault is noticed at most (:func:`poll_pause`).
POLL_PAUSE_MAX = 10.0


class DriveError(DeviceError):
    """The drive answered with an error, or could not be reached."""


class LinkError(DriveError):
    """No valid answer within the timeout after all retries, or the link is down. Unless the
    request never left (``outcome="not_executed"``, e.g. the port cannot be opened), whether
    the device executed it is unknown."""

    def __init__(self, message: str, outcome: str = "unknown") -> None:
        super().__init__(message)
        self.outcome = outcome


class NakError(DriveError):
    """The firmware refused the command; ``code`` is the rejection code (firmware_proto.faults)."""

    outcome = "not_executed"

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class MoveCancelled(Exception):
    """A wait was cancelled by its caller (not a drive failure); the drive may still move."""


# Status polls in a row that may go unanswered during a wait before its outcome is unknown.
MISSED_POLLS = 3


class ActuatorFault(DriveError):
    """The firmware reports latched faults (stall, limit switch, power cycle, ...)."""

    def __init__(self, message: str, faults: list[str]) -> None:
        super().__init__(message)
        self.faults = faults


@dataclass(frozen=True)
class AxisLimits:
    """Soft limits of one axis in motor steps, inclusive."""

    min_steps: int
    max_steps: int


@dataclass(frozen=True)
class DriveLimits:
    az: AxisLimits
    el: AxisLimits

    @classmethod
    def from_axes(cls, axes) -> DriveLimits:
        """From a :class:`controller.config.Axes`."""
        return cls(
            AxisLimits(axes.azimuth.soft_limits.min_steps, axes.azimuth.soft_limits.max_steps),
            AxisLimits(axes.elevation.soft_limits.min_steps, axes.elevation.soft_limits.max_steps),
        )

    def check(self, az_steps: int, el_steps: int, what: str = "target") -> None:
        """Raise :class:`LimitError` (exit 2) naming the axis when a target is out of range."""
        for name, value, lim in (("az", az_steps, self.az), ("el", el_steps, self.el)):
            if not isinstance(value, int) or isinstance(value, bool):
                raise LimitError(f"{what} {name}_steps must be an integer, got {value!r}")
            if not lim.min_steps <= value <= lim.max_steps:
                raise LimitError(
                    f"{what} {name}_steps={value} is outside the soft limits "
                    f"[{lim.min_steps}, {lim.max_steps}]; nothing was sent")


@dataclass(frozen=True)
class FirmwareInfo:
    """Firmware identification (serial GET_INFO, Modbus identification registers):
    protocol version, axes, hard step ranges, firmware version string."""

    protocol_version: int
    axes: int
    hard_limits: DriveLimits
    firmware_version: str


@dataclass(frozen=True)
class DriveStatus:
    """One status reading. ``faults`` holds the names from :func:`firmware_proto.faults.fault_names`."""

    unit: int
    az_steps: int
    el_steps: int
    az_target: int
    el_target: int
    moving: bool
    in_position: bool
    limit_az: bool = False
    limit_el: bool = False
    faults: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """The ``drive status --json`` contract."""
        return {"unit": self.unit, "az_steps": self.az_steps, "el_steps": self.el_steps,
                "moving": self.moving, "in_position": self.in_position,
                "faults": list(self.faults)}


@dataclass(frozen=True)
class MoveResult:
    """Outcome of a move or jog. ``retries`` counts retransmissions the link needed."""

    ok: bool
    az_steps: int
    el_steps: int
    retries: int = 0
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """The ``drive move|jog --json`` contract (``outcome``: the command was executed)."""
        return {"ok": self.ok, "az_steps": self.az_steps, "el_steps": self.el_steps,
                "retries": self.retries, "outcome": "executed"}


def poll_pause(poll_s: float, before: DriveStatus, now: DriveStatus, dt_s: float) -> float:
    """Plant seconds until the next status poll of a moving drive: a quarter of the time its
    slower axis still needs at the speed it moved since the last poll (``before``, ``dt_s``
    plant seconds ago),

        pause = clamp(¼ · max_axis |target − steps| · Δt / |Δsteps|, poll_s, POLL_PAUSE_MAX · poll_s),

    so a move of T seconds is read about log_{4/3}(T / poll_s) times instead of T / poll_s.
    A quarter, not a half: the speed read while an axis still accelerates from rest is low
    (0.1 s into the configured 0.5 s ramp, a tenth of the cruise speed), and with a quarter the
    end of every trapezoidal move is still caught within ``poll_s`` of it
    (tests/core/test_drive_polls.py). The cap bounds how late a stop or a fault is noticed.
    ``poll_s`` while an axis with steps to go has not moved (just commanded, or stalled)."""
    if dt_s <= 0.0:
        return poll_s
    eta = 0.0
    for pos, was, target in ((now.az_steps, before.az_steps, now.az_target),
                             (now.el_steps, before.el_steps, now.el_target)):
        to_go = abs(target - pos)
        if to_go:
            moved = abs(pos - was)
            if not moved:
                return poll_s
            eta = max(eta, to_go * dt_s / moved)
    return min(max(0.25 * eta, poll_s), POLL_PAUSE_MAX * poll_s)


class Drive(ABC):
    """A two-axis heliostat drive on some link.

    Subclasses implement the link-specific verbs; limit checks before sending and the
    move-and-wait helper are shared here. Every method raises :class:`DriveError`
    subclasses on failure, never returns a silent error.
    """

    unit: int
    limits: DriveLimits
    retries_used: int = 0  # retransmissions since the last reset, for reporting
    # Targets of the last move or jog as the firmware took them (a jog's result), else None.
    last_targets: tuple[int, int] | None = None

    @abstractmethod
    def status(self) -> DriveStatus: ...

    @abstractmethod
    def info(self) -> FirmwareInfo:
        """Firmware identification: protocol version, axes, hard step ranges, version string."""

    @abstractmethod
    def get_limits(self) -> DriveLimits:
        """The soft limits the firmware enforces."""

    @abstractmethod
    def set_limits(self, limits: DriveLimits) -> None:
        """Set the firmware's soft limits (it refuses limits that exclude its position/target)."""

    @abstractmethod
    def _send_move_abs(self, az_steps: int, el_steps: int) -> None: ...

    @abstractmethod
    def _send_jog(self, daz_steps: int, del_steps: int) -> None: ...

    @abstractmethod
    def stop(self) -> None: ...

    @abstractmethod
    def home(self) -> None: ...

    @abstractmethod
    def stow(self) -> None: ...

    @abstractmethod
    def clear_fault(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    def move_abs(self, az_steps: int, el_steps: int) -> None:
        """Command an absolute move; refused with LimitError before sending if out of range."""
        self.limits.check(az_steps, el_steps)
        self._send_move_abs(az_steps, el_steps)

    def jog(self, daz_steps: int, del_steps: int, *, from_status: DriveStatus | None = None) -> None:
        """Command a relative move. The resulting target (from the current *target*) is
        checked against the soft limits before anything is sent."""
        st = from_status or self.status()
        self.limits.check(st.az_target + daz_steps, st.el_target + del_steps, "jog result")
        self._send_jog(daz_steps, del_steps)

    def wait_in_position(self, timeout_s: float, time: PlantTime = DRIVE_TIME,
                         cancelled: Callable[[], bool] | None = None,
                         expect: tuple[int, int] | None = None,
                         watch: Callable[[DriveStatus], object] | None = None) -> DriveStatus:
        """Poll :meth:`status` until both axes are in position.

        One clock for the whole wait: the deadline ``timeout_s`` and the polling period are
        both plant seconds of ``time`` (a simulated plant hands in its plant clock). A long move
        is polled less often while it is far from its end (:func:`poll_pause`): every poll
        costs a bus transaction and the controller's time, and the end is still caught within
        ``time.poll_s``. ``expect``: the target this wait is for — a drive that stopped
        elsewhere, or sits idle with another target, is an error. ``watch``: called with every
        status read without a fault (to act on where the drive is along the move); while it
        returns True the next status is read after ``time.poll_s``.

        Raises :class:`MoveCancelled` as soon as ``cancelled()`` returns True,
        :class:`ActuatorFault` on latched faults, :class:`DriveError` on timeout or an
        unexpected position, and :class:`LinkError` (outcome unknown) after
        ``MISSED_POLLS`` status polls in a row got no answer; fewer are tolerated.
        """
        clock = time.now
        deadline = clock() + timeout_s
        missed = 0
        last: tuple[float, DriveStatus] | None = None
        while True:
            if cancelled is not None and cancelled():
                raise MoveCancelled(f"unit {self.unit}: wait cancelled; the drive may still be moving")
            try:
                st = self.status()
                missed = 0
            except LinkError as exc:
                missed += 1
                if missed >= MISSED_POLLS:
                    raise LinkError(f"{exc}; {missed} status polls in a row unanswered while waiting for "
                                    "the move: its outcome is unknown") from None
                st = None
            # Judging a status is the controller's own work (plant time runs at 1x there,
            # PlantTime.computing); the read itself waits for the plant's answer.
            with time.computing():
                if st is not None:
                    if st.faults:
                        raise ActuatorFault(f"unit {self.unit}: actuator fault {', '.join(st.faults)} at "
                                            f"az={st.az_steps} el={st.el_steps}", list(st.faults))
                    close = watch is not None and watch(st) is True
                    if st.in_position:
                        if expect is not None and (st.az_steps, st.el_steps) != expect:
                            raise DriveError(f"unit {self.unit}: stopped at ({st.az_steps}, {st.el_steps}), "
                                             f"commanded {expect}")
                        return st
                    if expect is not None and not st.moving and (st.az_target, st.el_target) != expect:
                        raise DriveError(f"unit {self.unit}: target changed to ({st.az_target}, "
                                         f"{st.el_target}) without a command (controller restarted?)")
                now = clock()
                if now >= deadline:
                    where = (f" (az {st.az_steps}->{st.az_target}, el {st.el_steps}->{st.el_target})"
                             if st is not None else "")
                    raise DriveError(f"unit {self.unit}: not in position after {timeout_s:g} s{where}")
                pause = time.poll_s
                if st is not None:
                    if last is not None and not close:
                        pause = poll_pause(time.poll_s, last[1], st, now - last[0])
                    last = (now, st)
            time.sleep(min(pause, max(time.poll_s, deadline - now)))

    def move_and_wait(self, az_steps: int, el_steps: int, *, timeout_s: float, time: PlantTime = DRIVE_TIME,
                      cancelled: Callable[[], bool] | None = None,
                      watch: Callable[[DriveStatus], object] | None = None) -> DriveStatus:
        """Absolute move (soft limits checked before sending), then :meth:`wait_in_position`
        for exactly that target on one clock. The one move-and-wait of the controller: the
        state machine, the CLI, commissioning, the console and the lamp change all use it."""
        self.move_abs(az_steps, el_steps)
        return self.wait_in_position(timeout_s, time, cancelled, (int(az_steps), int(el_steps)), watch)
