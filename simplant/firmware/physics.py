"""Actuator physics of the simulated heliostat drive controller.

One :class:`SimController` per bus address/unit id. It models two linear-actuator axes
(azimuth, elevation) with a trapezoidal speed profile (speed, acceleration), gear backlash,
soft limits (commands outside are refused) and hard limits (switches that latch a fault),
plus injected faults: stall, limit hit and power cycle.

Both simulated front ends (our serial frame protocol and Modbus) drive the same
:class:`SimController`, so the two links behave identically.

Time comes from an injected clock (seconds, monotonic), so tests can run motion without
sleeping; the plant clock may also run faster than real time.

Conventions: positions in motor steps. ``motor_steps`` is what the encoder on the motor
reports (the firmware's "actual steps"); ``output_steps`` is where the actuator rod really is,
which lags the motor by up to the backlash after a reversal. Only the simulated plant (the
camera's view of the beam) uses ``output_steps``: the controller never sees it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from firmware_proto.faults import Fault, Reject

Clock = Callable[[], float]

_DT_MAX = 0.005  # integration step, s: fine enough for ~1 step resolution at 1500 steps/s


@dataclass
class AxisParams:
    """Mechanical and limit parameters of one axis, in steps, steps/s and steps/s²."""

    soft_min: int
    soft_max: int
    hard_min: int
    hard_max: int
    speed: float = 1500.0
    acceleration: float = 3000.0
    backlash: int = 0
    home: int | None = None  # HOME target; default soft_min
    stow: int | None = None  # STOW target; default soft_min

    def __post_init__(self) -> None:
        if not self.hard_min <= self.soft_min < self.soft_max <= self.hard_max:
            raise ValueError(
                f"limits must satisfy hard_min <= soft_min < soft_max <= hard_max, got "
                f"{self.hard_min}, {self.soft_min}, {self.soft_max}, {self.hard_max}")


@dataclass
class SimAxis:
    """State of one axis. Call :meth:`advance` with elapsed time before reading it."""

    params: AxisParams
    motor: float = 0.0
    output: float = 0.0
    target: int = 0
    velocity: float = 0.0
    stalled: bool = False
    limit_hit: bool = False
    _last_dir: int = 0
    _slack: float = 0.0  # motor travel left before the output follows, after a reversal

    @property
    def moving(self) -> bool:
        return not self.stalled and not self.limit_hit and (
            abs(self.velocity) > 1e-9 or round(self.motor) != self.target)

    def set_target(self, target: int) -> None:
        self.target = int(target)

    def halt(self) -> None:
        """Stop where the axis is now (STOP, fault): the target becomes the position."""
        self.velocity = 0.0
        self.motor = float(round(self.motor))
        self.target = int(self.motor)

    def advance(self, dt: float) -> None:
        """Integrate motion over ``dt`` seconds with a trapezoidal profile and backlash."""
        if self.stalled or self.limit_hit:
            self.velocity = 0.0
            return
        p = self.params
        while dt > 1e-12:
            n = self._cruise_steps(dt)
            if n > 1:  # n whole steps at full speed at once: what n passes of the loop would do
                self._move_motor(math.copysign(p.speed * _DT_MAX * n, self.velocity))
                dt -= n * _DT_MAX
                continue
            h = min(dt, _DT_MAX)
            dt -= h
            remaining = self.target - self.motor
            if abs(remaining) < 0.5 and abs(self.velocity) < p.acceleration * h + 1e-9:
                self._move_motor(self.target - self.motor)
                self.velocity = 0.0
                return
            direction = math.copysign(1.0, remaining)
            stop_dist = self.velocity * self.velocity / (2.0 * p.acceleration)
            if self.velocity * direction < 0 or stop_dist >= abs(remaining):
                dv = -math.copysign(min(abs(self.velocity), p.acceleration * h), self.velocity)
            else:
                dv = direction * p.acceleration * h
            v_new = max(-p.speed, min(p.speed, self.velocity + dv))
            step = 0.5 * (self.velocity + v_new) * h
            if abs(step) > abs(remaining) and step * remaining > 0:
                step = remaining
                v_new = 0.0
            self.velocity = v_new
            self._move_motor(step)
            if not p.hard_min <= self.motor <= p.hard_max:
                self.motor = min(max(self.motor, p.hard_min), p.hard_max)
                self.limit_hit = True
                self.velocity = 0.0
                return

    def _cruise_steps(self, dt: float) -> int:
        """How many whole integration steps of the next ``dt`` s the axis cruises at full speed
        towards its target: each starts farther from it than the stopping distance and a step,
        so the loop would neither brake nor overshoot (0 when not cruising, or when the cruise
        would reach a hard limit, which the loop stops at step by step)."""
        p = self.params
        remaining = self.target - self.motor
        if abs(self.velocity) != p.speed or self.velocity * remaining <= 0:
            return 0
        # Each step starts farther than the stopping distance and than the step itself.
        near = max(p.speed * p.speed / (2.0 * p.acceleration), p.speed * _DT_MAX)
        n = min(int(dt / _DT_MAX), math.ceil((abs(remaining) - near) / (p.speed * _DT_MAX)))
        end = self.motor + math.copysign(p.speed * _DT_MAX * n, self.velocity)
        return n if n > 1 and p.hard_min <= end <= p.hard_max else 0

    def _move_motor(self, step: float) -> None:
        if step == 0:
            return
        d = 1 if step > 0 else -1
        if d != self._last_dir and self._last_dir != 0:
            # The motor crosses the gap back: only the part of it already crossed in the old
            # direction (a reversal inside the gap must not ratchet the output away).
            self._slack = float(self.params.backlash) - self._slack
        self._last_dir = d
        taken_by_slack = min(self._slack, abs(step))
        self._slack -= taken_by_slack
        self.motor += step
        self.output += d * (abs(step) - taken_by_slack)


@dataclass
class CommandLogEntry:
    """One executed command, as kept by the firmware's own log."""

    time: float
    command: str
    args: tuple[int, ...]
    result: Reject


@dataclass
class SimController:
    """A two-axis drive controller at one bus address / unit id.

    Thread-safe: the serial and Modbus servers call it from their own threads.
    All commands return a :class:`Reject` code (``Reject.OK`` when executed).
    """

    unit: int
    az: AxisParams
    el: AxisParams
    clock: Clock = time.monotonic
    firmware_version: str = "sim-1.0.0"
    initial_steps: tuple[int, int] | None = None
    log: list[CommandLogEntry] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._lock = threading.RLock()
        start = self.initial_steps or (self.az.stow or self.az.soft_min,
                                       self.el.stow or self.el.soft_min)
        self.axes = {"az": SimAxis(self.az), "el": SimAxis(self.el)}
        for axis, s in zip(self.axes.values(), start, strict=True):
            axis.motor = axis.output = float(s)
            axis.target = int(s)
        self.faults = Fault.NONE
        self._t = self.clock()

    # -- time -------------------------------------------------------------------------------
    def update(self) -> None:
        """Advance both axes to the clock's present time and latch any new faults."""
        with self._lock:
            now = self.clock()
            dt, self._t = max(0.0, now - self._t), now
            for name, axis in self.axes.items():
                was_hit = axis.limit_hit
                axis.advance(dt)
                if axis.limit_hit and not was_hit:
                    self.faults |= Fault.LIMIT_AZ if name == "az" else Fault.LIMIT_EL

    # -- commands ---------------------------------------------------------------------------
    def _record(self, command: str, args: tuple[int, ...], result: Reject) -> Reject:
        self.log.append(CommandLogEntry(self._t, command, args, result))
        return result

    def _check_targets(self, az: int, el: int) -> Reject:
        if not (self.az.soft_min <= az <= self.az.soft_max
                and self.el.soft_min <= el <= self.el.soft_max):
            return Reject.OUT_OF_RANGE
        if self.faults:
            return Reject.FAULT_ACTIVE
        return Reject.OK

    def move_abs(self, az: int, el: int) -> Reject:
        with self._lock:
            self.update()
            result = self._check_targets(az, el)
            if result == Reject.OK:
                self.axes["az"].set_target(az)
                self.axes["el"].set_target(el)
            return self._record("MOVE_ABS", (az, el), result)

    def jog(self, daz: int, delv: int) -> Reject:
        with self._lock:
            self.update()
            az = self.axes["az"].target + daz
            el = self.axes["el"].target + delv
            result = self._check_targets(az, el)
            if result == Reject.OK:
                self.axes["az"].set_target(az)
                self.axes["el"].set_target(el)
            return self._record("JOG", (daz, delv), result)

    def stop(self) -> Reject:
        with self._lock:
            self.update()
            for axis in self.axes.values():
                axis.halt()
            return self._record("STOP", (), Reject.OK)

    def _goto_preset(self, name: str, preset: str) -> Reject:
        with self._lock:
            self.update()
            az = getattr(self.az, preset) or self.az.soft_min
            el = getattr(self.el, preset) or self.el.soft_min
            result = self._check_targets(az, el)
            if result == Reject.OK:
                self.axes["az"].set_target(az)
                self.axes["el"].set_target(el)
            return self._record(name, (), result)

    def home(self) -> Reject:
        return self._goto_preset("HOME", "home")

    def stow(self) -> Reject:
        return self._goto_preset("STOW", "stow")

    def clear_fault(self) -> Reject:
        with self._lock:
            self.update()
            for axis in self.axes.values():
                axis.stalled = False
                if axis.limit_hit:
                    # Back inside the hard range by one step so the switch releases.
                    p = axis.params
                    axis.motor = float(min(max(round(axis.motor), p.hard_min + 1), p.hard_max - 1))
                    axis.limit_hit = False
                axis.halt()
            self.faults = Fault.NONE
            return self._record("CLEAR_FAULT", (), Reject.OK)

    def set_limits(self, az_min: int, az_max: int, el_min: int, el_max: int) -> Reject:
        """New soft limits, refused (nothing changed) while an axis moves (BUSY) or when they
        leave the hard range or exclude an axis's present position or target (BAD_LIMITS): an
        axis must never finish a move outside the soft range it is given."""
        with self._lock:
            self.update()
            new = {"az": (az_min, az_max), "el": (el_min, el_max)}
            if any(axis.moving for axis in self.axes.values()):
                result = Reject.BUSY
            elif not all(p.hard_min <= lo < hi <= p.hard_max for p, (lo, hi) in ((self.az, new["az"]),
                                                                                  (self.el, new["el"]))):
                result = Reject.BAD_LIMITS
            elif not all(lo <= round(a.motor) <= hi and lo <= a.target <= hi
                         for a, (lo, hi) in ((self.axes["az"], new["az"]), (self.axes["el"], new["el"]))):
                result = Reject.BAD_LIMITS
            else:
                self.az.soft_min, self.az.soft_max = az_min, az_max
                self.el.soft_min, self.el.soft_max = el_min, el_max
                result = Reject.OK
            return self._record("SET_LIMITS", (az_min, az_max, el_min, el_max), result)

    def restore_limits(self, az_min: int, az_max: int, el_min: int, el_max: int) -> None:
        """Put back soft limits a refused request changed (the server's rollback; not a command)."""
        with self._lock:
            self.az.soft_min, self.az.soft_max = az_min, az_max
            self.el.soft_min, self.el.soft_max = el_min, el_max

    # -- readings ---------------------------------------------------------------------------
    def status(self) -> dict:
        """Snapshot: actual/target motor steps, moving, in_position, limit switches, faults."""
        with self._lock:
            self.update()
            az, el = self.axes["az"], self.axes["el"]
            moving = az.moving or el.moving
            return {
                "az_steps": int(round(az.motor)), "el_steps": int(round(el.motor)),
                "az_target": az.target, "el_target": el.target,
                "moving": moving,
                "in_position": (not moving and not self.faults
                                and round(az.motor) == az.target and round(el.motor) == el.target),
                "limit_az": az.limit_hit, "limit_el": el.limit_hit,
                "faults": int(self.faults),
            }

    def output_steps(self) -> tuple[float, float]:
        """True rod positions (motor steps less backlash slack): the plant's ground truth."""
        with self._lock:
            self.update()
            return self.axes["az"].output, self.axes["el"].output

    # -- fault injection (simulation only) --------------------------------------------------
    def inject_stall(self, axis: str = "az") -> None:
        """The named axis stops dead and latches STALL until CLEAR_FAULT."""
        with self._lock:
            self.update()
            self.axes[axis].stalled = True
            self.axes[axis].velocity = 0.0
            self.faults |= Fault.STALL_AZ if axis == "az" else Fault.STALL_EL

    def inject_limit_hit(self, axis: str = "az") -> None:
        """The named axis hits its hard-limit switch: motion stops, LIMIT latches."""
        with self._lock:
            self.update()
            self.axes[axis].limit_hit = True
            self.axes[axis].velocity = 0.0
            self.faults |= Fault.LIMIT_AZ if axis == "az" else Fault.LIMIT_EL

    def power_cycle(self) -> None:
        """Controller restart: motion stops where it is (absolute encoders keep the position),
        targets reset to the position, POWER_CYCLE latches. Servers must also forget their
        duplicate-request caches."""
        with self._lock:
            self.update()
            for axis in self.axes.values():
                axis.halt()
                axis.stalled = axis.limit_hit = False
            self.faults = Fault.POWER_CYCLE
            self.log.append(CommandLogEntry(self._t, "POWER_CYCLE", (), Reject.OK))


def axis_params_from_config(axis) -> AxisParams:
    """Build :class:`AxisParams` from a config-like object with the AxisConfig fields
    (``soft_limits.min_steps`` …, ``min_increment``, ``speed_steps_per_s`` …)."""
    return AxisParams(
        soft_min=axis.soft_limits.min_steps, soft_max=axis.soft_limits.max_steps,
        hard_min=axis.min_increment, hard_max=axis.max_increment,
        speed=axis.speed_steps_per_s, acceleration=axis.acceleration_steps_per_s2,
        backlash=axis.backlash_steps,
    )
