"""The nominal aim of heliostats (no error model) at the calibration target under the
calibration lamp: ``heliocal campaign demo --aim-only`` prints it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.config import LampSource, PlantConfig
from controller.errors import InputError
from controller.geometry.aiming import aim_normal, source_direction
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import vector_to_azel


@dataclass(frozen=True)
class NominalAim:
    """Aim of one heliostat with the nominal kinematics (no error model): light-source
    direction and mirror normal (ENU unit vectors), normal azimuth/elevation (degrees,
    azimuth clockwise from north) and motor steps."""

    heliostat_id: str
    source_dir: np.ndarray
    normal: np.ndarray
    az_deg: float
    el_deg: float
    az_steps: int
    el_steps: int


def nominal_aims(cfg: PlantConfig, ids: list[str]) -> list[NominalAim]:
    """Nominal aim of each heliostat at the calibration target's centre under the
    calibration light source (a lamp)."""
    src = cfg.light_source()
    if not isinstance(src, LampSource):
        raise InputError("calibration.light_source must be a lamp for a nightly aim")
    target = np.asarray(cfg.target().center_enu_m, float)
    out = []
    for hid in ids:
        h = cfg.heliostat(hid)
        pos = np.asarray(h.position_enu_m, float)
        s = source_direction(src, pos)
        normal = aim_normal(s, pos, target)
        az, el = vector_to_azel(normal)
        a, e = HeliostatKinematics.from_config(h).steps_for_normal(normal)
        out.append(NominalAim(hid, s, normal, float(az), float(el), int(a), int(e)))
    return out
