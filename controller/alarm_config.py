"""The ``alarms:`` section of the plant configuration (docs/plant-integration.md,
docs/configuration.md): the limits beyond which a heliostat's errors raise an alarm.
Re-exported by :mod:`controller.config`."""

from __future__ import annotations

from pydantic import Field

from controller.config_rules import Section


class AlarmLimits(Section):
    daytime_error_limit_mrad: float = Field(
        default=2.0, gt=0, le=1000, description="a heliostat's predicted daytime RMS error above this "
        "(mrad) raises daytime_error_high at the end of a night")
    drift_limit_mrad: float = Field(
        default=5.0, gt=0, le=1000, description="a heliostat's pointing error measured with its model "
        "before any correction above this (mrad) raises drift_high")
    link_failures: int = Field(default=3, ge=1, le=1000, description="drive status readings failed in a "
                               "row (console, OPC UA) before drive_link_down is raised")
