"""The axes of the plant configuration (``heliostats[i].axes``, docs/configuration.md): two
linear-actuator axes per heliostat, with the names and units of the PAINT/ARTIST heliostat
records, their hard range and soft limits. Re-exported by :mod:`controller.config`, whose
:func:`load_config` validates it.
"""

from __future__ import annotations

import math

from pydantic import Field, model_validator

from controller.config_rules import INT32_MAX, Section, Steps

_Model = Section  # as every configuration section (controller.config_rules)


class SoftLimits(_Model):
    min_steps: Steps
    max_steps: Steps

    @model_validator(mode="after")
    def _ordered(self) -> SoftLimits:
        if self.min_steps >= self.max_steps:
            raise ValueError(f"min_steps ({self.min_steps}) must be below max_steps ({self.max_steps})")
        return self


class AxisConfig(_Model):
    """One linear-actuator axis. Names and units as in the PAINT/ARTIST heliostat records."""

    increment: float = Field(gt=0, le=1e9, description="motor steps per metre of stroke")
    initial_stroke_length: float = Field(gt=0, le=10, description="stroke L0 at step 0, m")
    offset: float = Field(gt=0, le=10, description="actuator mount offset from the pivot, m")
    pivot_radius: float = Field(gt=0, le=10, description="lever arm from pivot to actuator rod end, m")
    initial_angle: float = Field(ge=-math.pi, le=math.pi, description="axis angle at step 0, rad")
    clockwise_axis_movement: bool = False
    # Steps travel as int32 on both wire protocols (PROTOCOL.md, MODBUS.md).
    min_increment: int = Field(ge=0, le=INT32_MAX, description="hard range start, steps")
    max_increment: int = Field(gt=0, le=INT32_MAX, description="hard range end, steps")
    soft_limits: SoftLimits
    speed_steps_per_s: float = Field(default=1500.0, gt=0, le=100000)
    acceleration_steps_per_s2: float = Field(default=3000.0, gt=0, le=1000000)
    backlash_steps: int = Field(default=0, ge=0, le=1000)

    @model_validator(mode="after")
    def _limits_inside_range(self) -> AxisConfig:
        if self.min_increment >= self.max_increment:
            raise ValueError("min_increment must be below max_increment")
        lo, hi = self.soft_limits.min_steps, self.soft_limits.max_steps
        if lo < self.min_increment or hi > self.max_increment:
            raise ValueError(
                f"soft_limits [{lo}, {hi}] must lie inside the hard range "
                f"[{self.min_increment}, {self.max_increment}]"
            )
        # The stroke L = s / increment + L0 must close the actuator triangle (docs/geometry.md)
        # over the whole soft range, or a commanded step has no joint angle.
        short, long = abs(self.offset - self.pivot_radius), self.offset + self.pivot_radius
        first, last = (s / self.increment + self.initial_stroke_length for s in (lo, hi))
        if first < short or last > long:
            raise ValueError(
                f"soft_limits [{lo}, {hi}] give strokes [{first:.4f}, {last:.4f}] m, outside the actuator "
                f"triangle [{short:.4f}, {long:.4f}] m (|offset − pivot_radius|, offset + pivot_radius)")
        return self


class Axes(_Model):
    azimuth: AxisConfig
    elevation: AxisConfig
