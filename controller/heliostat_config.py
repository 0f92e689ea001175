"""The heliostats of the plant configuration (``heliostats``, docs/configuration.md): each one's
position, mirror, two linear-actuator axes and link — or, for a large field, the ``field``
section that keeps them in a file of their own (a CSV of id, position, kinematics reference,
bus and station, read by :mod:`controller.field_file`). Re-exported by
:mod:`controller.config`, whose :func:`load_config` validates it.
"""

from __future__ import annotations

import math

from pydantic import Field, model_validator

from controller.config_rules import INT32_MAX, Position, Section, Steps
from controller.link_config import Bus, Link

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
        return self


class Axes(_Model):
    azimuth: AxisConfig
    elevation: AxisConfig


class Mirror(_Model):
    width_m: float = Field(gt=0, le=30)
    height_m: float = Field(gt=0, le=30)
    focal_length_m: float = Field(gt=0, le=10000, description="on-axis focal length, m")
    slope_error_mrad: float = Field(default=1.5, ge=0, le=20)
    reflectivity: float = Field(default=0.93, gt=0, le=1)


class Heliostat(_Model):
    id: str
    position_enu_m: Position
    mirror: Mirror
    axes: Axes
    link: Link


class Kinematics(_Model):
    """A heliostat design the field file refers to by name: its mirror and its axes."""

    mirror: Mirror
    axes: Axes


class FieldFile(_Model):
    """The heliostats in a file of their own (docs/configuration.md, "The field in its own
    file"): ``file`` (relative to the configuration's folder) has a row per heliostat naming one
    entry of ``kinematics`` and one of ``buses``."""

    file: str = Field(min_length=1, max_length=4096, description="the field file (CSV)")
    kinematics: dict[str, Kinematics] = Field(min_length=1, max_length=1000,
                                              description="heliostat designs, by the name rows give")
    buses: dict[str, Bus] = Field(min_length=1, max_length=10000,
                                  description="buses and gateways, by the name rows give")
