"""The heliostats of the plant configuration (``heliostats``, docs/configuration.md): each one's
position, mirror, two linear-actuator axes and link — or, for a large field, the ``field``
section that keeps them in a file of their own (a CSV of id, position, kinematics reference,
bus and station, read by :mod:`controller.field_file`). Re-exported by
:mod:`controller.config`, whose :func:`load_config` validates it.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from controller.axis_config import Axes
from controller.config_rules import Position, Section
from controller.link_config import Bus, Link

_Model = Section  # as every configuration section (controller.config_rules)
class Mirror(_Model):
    width_m: float = Field(gt=0, le=30)
    height_m: float = Field(gt=0, le=30)
    focal_length_m: float = Field(gt=0, le=10000, description="on-axis focal length, m")
    slope_error_mrad: float = Field(default=1.5, ge=0, le=20)
    reflectivity: float = Field(default=0.93, gt=0, le=1)


Translation = Annotated[float, Field(ge=-10, le=10)]


class Heliostat(_Model):
    id: str
    position_enu_m: Position
    mirror: Mirror
    axes: Axes
    link: Link
    concentrator_translation_m: tuple[Translation, Translation, Translation] = Field(
        default=(0.0, 0.0, 0.0), description="mirror centre from the pivot in the body frame (facing "
        "south: east, north, up), m; PAINT/ARTIST concentrator_translation_{e,n,u}")


class Kinematics(_Model):
    """A heliostat design the field file refers to by name: its mirror, its axes and where the
    mirror centre sits from the pivot."""

    mirror: Mirror
    axes: Axes
    concentrator_translation_m: tuple[Translation, Translation, Translation] = (0.0, 0.0, 0.0)


class FieldFile(_Model):
    """The heliostats in a file of their own (docs/configuration.md, "The field in its own
    file"): ``file`` (relative to the configuration's folder) has a row per heliostat naming one
    entry of ``kinematics`` and one of ``buses``."""

    file: str = Field(min_length=1, max_length=4096, description="the field file (CSV)")
    kinematics: dict[str, Kinematics] = Field(min_length=1, max_length=1000,
                                              description="heliostat designs, by the name rows give")
    buses: dict[str, Bus] = Field(min_length=1, max_length=10000,
                                  description="buses and gateways, by the name rows give")
