"""Linear actuators: motor steps <-> stroke length <-> joint angle, with soft limits.

A linear actuator pushes a lever of length ``pivot_radius`` about the joint. The actuator's
own pivot sits ``offset`` from the joint, so joint, actuator pivot and rod end form a triangle
with sides ``offset`` (o), ``pivot_radius`` (r) and the stroke L. The angle at the joint is, by
the law of cosines,

    φ(L) = arccos((o² + r² − L²) / (2 o r)),                        (1)

and the stroke is linear in motor steps s:

    L(s) = s / increment + L₀,        L₀ = initial_stroke_length.    (2)

The joint angle is measured from the angle ``initial_angle`` θ₀ that the joint has at s = 0:

    θ(s) = θ₀ − (φ(L₀) − φ(L(s)))   when clockwise_axis_movement is false,
    θ(s) = θ₀ + (φ(L₀) − φ(L(s)))   when it is true,                  (3)

so a counter-clockwise axis opens with more steps, a clockwise one closes. Names and units are
those of the PAINT/ARTIST heliostat records (``increment`` in steps per metre, lengths in m,
angles in rad); Eq. (1)-(3) are ARTIST's ``LinearActuator`` and reproduce the AA39 records
(docs/geometry.md).

References
----------
.. [1] M. Pargmann et al., "In-situ calibration of heliostats by differentiable ray tracing"
   (ARTIST), Nature Communications 15, 6997, 2024; linear-actuator kinematics in the ARTIST
   source, ``artist/field/actuator_linear.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.errors import LimitError


def stroke_from_steps(steps, increment: float, initial_stroke_length: float):
    """Stroke length L, m, for motor steps s: L = s / increment + L₀ (Eq. 2)."""
    return np.asarray(steps, dtype=float) / increment + initial_stroke_length


def steps_from_stroke(stroke_m, increment: float, initial_stroke_length: float):
    """Motor steps (float) for stroke L, m: s = (L − L₀) · increment (inverse of Eq. 2)."""
    return (np.asarray(stroke_m, dtype=float) - initial_stroke_length) * increment


def lever_angle(stroke_m, offset: float, pivot_radius: float):
    """Angle at the joint, rad, opposite the stroke in the (o, r, L) triangle (Eq. 1).

    Raises ValueError when no triangle exists (|o − r| ≤ L ≤ o + r is violated).
    """
    c = (offset**2 + pivot_radius**2 - np.asarray(stroke_m, dtype=float) ** 2) / (2.0 * offset * pivot_radius)
    if (np.abs(c) > 1.0).any():  # the method: np.any's dispatch costs more than the test
        raise ValueError(f"stroke outside the actuator triangle [{abs(offset - pivot_radius):.6g}, "
                         f"{offset + pivot_radius:.6g}] m")
    return np.arccos(c)


def stroke_from_lever_angle(phi_rad, offset: float, pivot_radius: float):
    """Stroke L, m, for the joint-side triangle angle φ: L² = o² + r² − 2 o r cos φ (Eq. 1)."""
    return np.sqrt(offset**2 + pivot_radius**2 - 2.0 * offset * pivot_radius * np.cos(phi_rad))


@dataclass(frozen=True)
class LinearActuator:
    """One linear-actuator axis: geometry as in the PAINT/ARTIST records plus its limits.

    ``min_steps``/``max_steps`` are the soft limits that commands must respect (inside the hard
    range ``min_increment``..``max_increment``).
    """

    name: str
    increment: float
    initial_stroke_length: float
    offset: float
    pivot_radius: float
    initial_angle: float
    clockwise_axis_movement: bool
    min_increment: int
    max_increment: int
    min_steps: int
    max_steps: int

    @classmethod
    def from_config(cls, name: str, axis) -> LinearActuator:
        """From a :class:`controller.config.AxisConfig` (soft limits from ``soft_limits``)."""
        return cls(name, axis.increment, axis.initial_stroke_length, axis.offset, axis.pivot_radius,
                   axis.initial_angle, bool(axis.clockwise_axis_movement), axis.min_increment,
                   axis.max_increment, axis.soft_limits.min_steps, axis.soft_limits.max_steps)

    @classmethod
    def from_aa39(cls, name: str, actuator: dict) -> LinearActuator:
        """From one entry of a PAINT/ARTIST ``kinematics_properties.actuators`` list.

        The record has no soft limits, so the hard range is used for them.
        """
        lo, hi = int(actuator["min_increment"]), int(actuator["max_increment"])
        return cls(name, float(actuator["increment"]), float(actuator["initial_stroke_length"]),
                   float(actuator["offset"]), float(actuator["pivot_radius"]),
                   float(actuator["initial_angle"]), bool(actuator["clockwise_axis_movement"]),
                   lo, hi, lo, hi)

    @property
    def _sign(self) -> float:
        return 1.0 if self.clockwise_axis_movement else -1.0

    def stroke(self, steps):
        """Stroke length, m, at motor steps (Eq. 2)."""
        return stroke_from_steps(steps, self.increment, self.initial_stroke_length)

    def angle(self, steps):
        """Joint angle θ, rad, at motor steps (float or array; Eq. 1-3). No limit check."""
        phi0 = lever_angle(self.initial_stroke_length, self.offset, self.pivot_radius)
        return self.initial_angle + self._sign * (phi0 - lever_angle(self.stroke(steps), self.offset,
                                                                      self.pivot_radius))

    def steps_float(self, angle_rad):
        """Motor steps (unrounded) giving joint angle θ, rad: inverse of Eq. 3, 1, 2."""
        phi0 = lever_angle(self.initial_stroke_length, self.offset, self.pivot_radius)
        phi = phi0 - self._sign * (np.asarray(angle_rad, dtype=float) - self.initial_angle)
        if ((phi < 0.0) | (phi > math.pi)).any():
            raise LimitError(f"{self.name} axis: angle {np.degrees(angle_rad):.4f}° cannot be reached by "
                             "the actuator (no actuator triangle)")
        return steps_from_stroke(stroke_from_lever_angle(phi, self.offset, self.pivot_radius),
                                 self.increment, self.initial_stroke_length)

    def steps(self, angle_rad: float) -> int:
        """Nearest whole motor step for joint angle θ, rad; LimitError outside the soft limits."""
        s = float(self.steps_float(angle_rad))
        steps = int(round(s))
        self.check(steps, what=f"angle {math.degrees(angle_rad):.4f}°")
        return steps

    def check(self, steps: float, what: str = "target") -> None:
        """Raise LimitError naming the axis and value when ``steps`` is outside the soft limits."""
        if not self.min_steps <= steps <= self.max_steps:
            raise LimitError(f"{self.name} axis: {what} needs {steps:.0f} steps, outside the soft limits "
                             f"[{self.min_steps}, {self.max_steps}]")

    def angle_range(self) -> tuple[float, float]:
        """(lowest, highest) joint angle, rad, reachable inside the soft limits."""
        a, b = float(self.angle(self.min_steps)), float(self.angle(self.max_steps))
        return (min(a, b), max(a, b))

    def angle_per_step(self, steps: float) -> float:
        """dθ/ds, rad per step, at ``steps`` (central difference over ±0.5 step)."""
        return float(self.angle(steps + 0.5) - self.angle(steps - 0.5))
