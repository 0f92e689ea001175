"""Fixtures: the real Jülich AA39 / PAINT records and the demo configuration."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from controller.config import load_config
from controller.geometry.frames import paint_azimuth_to_north, wgs84_to_enu
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import azel_to_vector

REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "tests" / "data" / "real"  # the real Jülich records (see its README)


def _load(path: Path) -> dict:
    if not path.is_file():
        pytest.skip(f"real data not available: {path}")
    return json.loads(path.read_text())


@pytest.fixture(scope="session")
def tower() -> dict:
    return _load(REAL / "aa39" / "tower-measurements.json")


@pytest.fixture(scope="session")
def origin(tower) -> tuple[float, float, float]:
    """WGS84 origin of the local ENU frame: the Jülich plant reference point."""
    return tuple(tower["power_plant_properties"]["coordinates"])


@pytest.fixture(scope="session")
def aa39_properties() -> dict:
    return _load(REAL / "aa39" / "AA39-heliostat-properties.json")


@pytest.fixture(scope="session")
def aa39(aa39_properties, origin) -> HeliostatKinematics:
    return HeliostatKinematics.from_aa39(aa39_properties, origin)


@pytest.fixture(scope="session")
def aa39_records(tower, origin) -> list[dict]:
    """The three AA39 calibration records in ENU: sun direction, steps, UTIS spot, target plane."""
    out = []
    for i in (1, 2, 3):
        r = _load(REAL / "aa39" / f"AA39-calibration-properties_{i}.json")
        t = tower[r["target_name"]]
        out.append({
            "sun": azel_to_vector(paint_azimuth_to_north(r["sun_azimuth"]), r["sun_elevation"]),
            "az_steps": r["motor_position"]["axis_2_motor_position"],
            "el_steps": r["motor_position"]["axis_1_motor_position"],
            "spot": wgs84_to_enu(*r["focal_spot"]["UTIS"], *origin),
            "spot_helios": wgs84_to_enu(*r["focal_spot"]["HeliOS"], *origin),
            "plane_point": wgs84_to_enu(*t["coordinates"]["center"], *origin),
            "plane_normal": np.array(t["normal_vector"], dtype=float),
        })
    return out


@pytest.fixture(scope="session")
def paint_records() -> list[dict]:
    folder = REAL / "paint"
    if not folder.is_dir():
        pytest.skip(f"real data not available: {folder}")
    return [json.loads(p.read_text()) for p in sorted(folder.glob("*-calibration-properties.json"))]


@pytest.fixture(scope="session")
def demo_config():
    return load_config(REPO / "configs" / "demo.yaml")
