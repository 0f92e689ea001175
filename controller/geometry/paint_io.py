"""Read PAINT/ARTIST files — heliostat properties, tower measurements, calibration records —
into the plant's ENU frame (origin: the tower file's ``power_plant_properties.coordinates``).

Formats (those of the PAINT database of the Jülich solar tower and of ARTIST's test data):

* heliostat properties: ``heliostat_position`` [lat, lon, alt] and
  ``kinematics_properties.actuators`` (``[0]`` the elevation joint, ``[1]`` azimuth), each with
  ``increment`` (steps/m), ``initial_stroke_length``, ``offset``, ``pivot_radius`` (m),
  ``initial_angle`` (rad), ``clockwise_axis_movement``, ``min_increment``/``max_increment``,
  plus ``concentrator_translation_{e,n,u}`` (m);
* tower measurements: per target ``normal_vector`` (ENU) and ``coordinates.center`` (WGS84);
* a calibration record: ``motor_position.axis_1_motor_position`` (elevation steps) and
  ``axis_2_motor_position`` (azimuth), ``target_name``, ``sun_azimuth`` (degrees from **south**,
  positive towards east) and ``sun_elevation``, ``focal_spot.{UTIS,HeliOS}`` [lat, lon, alt].

Every file goes through the bounded reader (size, UTF-8, nesting); a missing or wrong key
raises InputError naming the file and key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.geometry.frames import paint_azimuth_to_north, wgs84_to_enu
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model_fit import Sample
from controller.geometry.vectors import azel_to_vector
from controller.io.json_files import parse_json
from controller.io.yaml_files import read_text

FOCAL_SPOT_METHODS = ("UTIS", "HeliOS")


def _load_json(path: str | Path, what: str):
    """A JSON object from ``path`` through the bounded text reader; InputError naming the file."""
    data = parse_json(read_text(path, what), str(path))  # depth bounded before parsing
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object in the {what}")
    return data


def _get(data, path: str, source: str):
    node = data
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            raise InputError(f"{source}: missing key {path!r}")
        node = node[part]
    return node


def _numbers(value, n: int, key: str, source: str) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise InputError(f"{source}: {key} must be a list of {n} finite numbers, got {str(value)[:60]}")
    return np.asarray(value, dtype=float)


def _number(value, key: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{source}: {key} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)  # numpy fields
class TargetPlane:
    """A tower target: ``name``, centre (m ENU) and unit plane normal (ENU)."""

    name: str
    center_enu: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class Towers:
    """Targets of a tower-measurements file and the WGS84 origin of the plant frame."""

    origin_wgs84: tuple[float, float, float]
    targets: dict[str, TargetPlane]

    def target(self, name: str, source: str = "record") -> TargetPlane:
        if name not in self.targets:
            raise InputError(f"{source}: target {name!r} is not in the towers file "
                             f"(known: {', '.join(sorted(self.targets))})")
        return self.targets[name]


def read_towers(path: str | Path) -> Towers:
    """The targets of a ``tower-measurements.json`` file."""
    src = str(path)
    data = _load_json(path, "towers file")
    origin = tuple(float(v) for v in _numbers(_get(data, "power_plant_properties.coordinates", src), 3,
                                              "power_plant_properties.coordinates", src))
    targets = {}
    for name, t in data.items():
        if name == "power_plant_properties":
            continue
        center = _numbers(_get(t, "coordinates.center", f"{src}: {name}"), 3, f"{name}.coordinates.center",
                          src)
        normal = _numbers(_get(t, "normal_vector", f"{src}: {name}"), 3, f"{name}.normal_vector", src)
        if np.linalg.norm(normal) == 0:
            raise InputError(f"{src}: {name}.normal_vector is zero")
        targets[name] = TargetPlane(name, wgs84_to_enu(*center, *origin), normal / np.linalg.norm(normal))
    if not targets:
        raise InputError(f"{src}: no targets")
    return Towers(origin, targets)  # type: ignore[arg-type]


def read_heliostat_properties(path: str | Path) -> dict:
    """The raw properties mapping, checked for every key the kinematics needs."""
    src = str(path)
    data = _load_json(path, "heliostat properties")
    check_heliostat_properties(data, src)
    return data


def check_heliostat_properties(data: dict, src: str) -> None:
    """InputError naming the key when ``data`` lacks what :func:`kinematics_from_properties` reads."""
    _numbers(_get(data, "heliostat_position", src), 3, "heliostat_position", src)
    acts = _get(data, "kinematics_properties.actuators", src)
    if not isinstance(acts, list) or len(acts) != 2:
        raise InputError(f"{src}: kinematics_properties.actuators must list two actuators")
    for i, a in enumerate(acts):
        for key in ("increment", "initial_stroke_length", "offset", "pivot_radius", "initial_angle",
                    "min_increment", "max_increment", "clockwise_axis_movement"):
            v = _number(_get(a, key, f"{src}: actuators[{i}]"), f"actuators[{i}].{key}", src)
            if key in ("increment", "offset", "pivot_radius") and v <= 0:
                raise InputError(f"{src}: actuators[{i}].{key} must be > 0, got {v}")


def kinematics_from_properties(properties: dict, origin_wgs84,
                               heliostat_id: str = "heliostat") -> HeliostatKinematics:
    """Nominal kinematics from a checked properties mapping, in the plant frame at ``origin_wgs84``."""
    return HeliostatKinematics.from_aa39(properties, origin_wgs84, heliostat_id)


@dataclass(frozen=True, eq=False)  # numpy fields
class PaintRecord:
    """One calibration record in the plant frame: the fit's :class:`Sample` (UTIS spot), the
    target plane, the sun angles (azimuth clockwise from north, degrees) and every method's
    focal spot (m ENU)."""

    source: str
    sample: Sample
    target: TargetPlane
    sun_azimuth_deg: float
    sun_elevation_deg: float
    focal_spots: dict[str, np.ndarray]


def read_record(path: str | Path, towers: Towers, *, with_spot: bool = True) -> PaintRecord:
    """A calibration record. ``with_spot=False`` reads no focal spot (for a prediction, which
    must not see the measurement): ``sample.spot_enu`` is then NaN."""
    src = str(path)
    data = _load_json(path, "calibration record")
    el_steps = _number(_get(data, "motor_position.axis_1_motor_position", src), "axis_1_motor_position", src)
    az_steps = _number(_get(data, "motor_position.axis_2_motor_position", src), "axis_2_motor_position", src)
    name = _get(data, "target_name", src)
    if not isinstance(name, str):
        raise InputError(f"{src}: target_name must be a string")
    target = towers.target(name, src)
    sun_el = _number(_get(data, "sun_elevation", src), "sun_elevation", src)
    paint_az = _number(_get(data, "sun_azimuth", src), "sun_azimuth", src)
    sun_az = float(paint_azimuth_to_north(paint_az)) % 360.0
    if not 0.0 < sun_el <= 90.0:
        raise InputError(f"{src}: sun_elevation {sun_el} is not above the horizon")
    spots: dict[str, np.ndarray] = {}
    if with_spot:
        fs = _get(data, "focal_spot", src)
        for method in FOCAL_SPOT_METHODS:
            if isinstance(fs, dict) and method in fs:
                spots[method] = wgs84_to_enu(*_numbers(fs[method], 3, f"focal_spot.{method}", src),
                                             *towers.origin_wgs84)
        if "UTIS" not in spots:
            raise InputError(f"{src}: missing key 'focal_spot.UTIS'")
    spot = spots.get("UTIS", np.full(3, np.nan))
    sample = Sample(azel_to_vector(sun_az, sun_el), az_steps, el_steps, spot)
    return PaintRecord(src, sample, target, sun_az, sun_el, spots)


@dataclass(frozen=True)
class PaintSet:
    """The inputs of a fit on PAINT/ARTIST files: towers, the heliostat's id (from the
    properties file's name, ``<id>-heliostat-properties.json``), properties, nominal
    kinematics and the records."""

    towers: Towers
    heliostat_id: str
    properties: dict
    kinematics: HeliostatKinematics
    records: list[PaintRecord]


def read_paint_set(records: list[str], properties: str | Path, towers: str | Path) -> PaintSet:
    """Read and check every file of a fit (InputError naming the file and key)."""
    tw = read_towers(towers)
    props = read_heliostat_properties(properties)
    hid = Path(properties).stem.split("-")[0]
    kin = kinematics_from_properties(props, tw.origin_wgs84, hid)
    return PaintSet(tw, hid, props, kin, [read_record(r, tw) for r in records])
