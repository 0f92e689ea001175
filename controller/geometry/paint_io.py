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
  positive towards east) and ``sun_elevation``, ``focal_spot.{UTIS,HeliOS}`` [lat, lon, alt];
* timestamps: ``{"<heliostat>_<record id>": UTC time}`` (PAINT's ``timestamps.json``).

Every file goes through the bounded reader (size, UTF-8, nesting); a missing or wrong key
raises InputError naming the file and key.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from controller.errors import InputError
from controller.geometry.frames import paint_azimuth_to_north, wgs84_to_enu
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.fit import Sample
from controller.geometry.vectors import azel_to_vector
from controller.io.json_files import parse_json
from controller.io.text_numbers import is_ascii_index
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


# Physical ranges of a record's values, checked before any fit (a latitude of 91° or a spot 600 km
# from its tower fitted "successfully" before): WGS84 degrees; altitude, m; a measured focal spot lies
# on its target, within MAX_SPOT_OFFSET_M of the surveyed centre (targets are a few metres wide).
ALTITUDE_M = (-500.0, 9000.0)
MAX_SPOT_OFFSET_M = 100.0
SUN_AZIMUTH_DEG = (-360.0, 360.0)  # PAINT's (-180, 180], or the same angle written from 0 to 360


def _wgs84(value, key: str, source: str) -> np.ndarray:
    """[lat_deg, lon_deg, alt_m]: three finite numbers within lat [-90, 90], lon [-180, 180] and
    :data:`ALTITUDE_M`; InputError naming the key and value."""
    v = _numbers(value, 3, key, source)
    for x, (lo, hi), what in zip(v, ((-90.0, 90.0), (-180.0, 180.0), ALTITUDE_M), ("latitude", "longitude",
                                                                                  "altitude"), strict=True):
        if not lo <= x <= hi:
            raise InputError(f"{source}: {key}: {what} {x:g} is outside [{lo:g}, {hi:g}]")
    return v


def check_reach(record: PaintRecord, kinematics: HeliostatKinematics) -> None:
    """The record's motor positions are steps the heliostat's actuators can take: inside each
    actuator's hard range [min_increment, max_increment] of the properties file; InputError
    naming the record, key and value. (Not the nominal triangle: a wrong initial stroke is
    re-seated by the fit, :mod:`controller.geometry.model.fit`.)"""
    axes = (("axis_1_motor_position", record.sample.el_steps, kinematics.elevation),
            ("axis_2_motor_position", record.sample.az_steps, kinematics.azimuth))
    for key, steps, act in axes:
        lo, hi = act.min_increment, act.max_increment
        if not lo <= steps <= hi:
            raise InputError(f"{record.source}: motor_position.{key} {steps:g} is outside what the "
                             f"{act.name} actuator can take ([{lo:.0f}, {hi:.0f}] steps)")


def _number(value, key: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{source}: {key} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)  # numpy fields
class TargetPlane:
    """A tower target: ``name``, centre (m ENU), unit plane normal (ENU) and, when the file
    surveys more points than the centre (its corners), ``size_m``: (width, height) in m."""

    name: str
    center_enu: np.ndarray
    normal: np.ndarray
    size_m: tuple[float, float] | None = None


@dataclass(frozen=True)
class Towers:
    """Targets of a tower-measurements file, the WGS84 origin of the plant frame and the
    plant's ``power_plant_properties.ID`` ("" when absent); ``described_by`` names the file
    the targets came from in messages."""

    origin_wgs84: tuple[float, float, float]
    targets: dict[str, TargetPlane]
    plant_id: str = ""
    described_by: str = "the towers file"

    def target(self, name: str, source: str = "record") -> TargetPlane:
        if name not in self.targets:
            raise InputError(f"{source}: target {name!r} is not in {self.described_by} "
                             f"(known: {', '.join(sorted(self.targets))})")
        return self.targets[name]


def read_towers(path: str | Path) -> Towers:
    """The targets of a ``tower-measurements.json`` file."""
    src = str(path)
    data = _load_json(path, "towers file")
    origin = tuple(float(v) for v in _wgs84(_get(data, "power_plant_properties.coordinates", src),
                                            "power_plant_properties.coordinates", src))
    targets = {}
    for name, t in data.items():
        if name == "power_plant_properties":
            continue
        center = _wgs84(_get(t, "coordinates.center", f"{src}: {name}"), f"{name}.coordinates.center", src)
        normal = _numbers(_get(t, "normal_vector", f"{src}: {name}"), 3, f"{name}.normal_vector", src)
        if np.linalg.norm(normal) == 0:
            raise InputError(f"{src}: {name}.normal_vector is zero")
        normal = normal / np.linalg.norm(normal)
        center_enu = wgs84_to_enu(*center, *origin)
        points = [wgs84_to_enu(*_wgs84(v, f"{name}.coordinates.{key}", src), *origin)
                  for key, v in t["coordinates"].items() if key != "center"]
        targets[name] = TargetPlane(name, center_enu, normal, plane_extent(center_enu, normal, points))
    if not targets:
        raise InputError(f"{src}: no targets")
    plant_id = data["power_plant_properties"].get("ID")
    return Towers(origin, targets, plant_id if isinstance(plant_id, str) else "")  # type: ignore[arg-type]


def plane_extent(center, normal, points) -> tuple[float, float] | None:
    """(width, height), m, of ``points`` and ``center`` (m ENU) on a plane of unit ``normal``:
    their spread along the plane's level axis h = (ẑ × n)/|ẑ × n| (east for a level plane) and
    along v = n × h. None without points."""
    if not points:
        return None
    n = np.asarray(normal, float)
    h = np.cross([0.0, 0.0, 1.0], n)
    h = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-9 else np.array([1.0, 0.0, 0.0])
    rel = np.asarray([*points, center], float) - np.asarray(center, float)
    return float(np.ptp(rel @ h)), float(np.ptp(rel @ np.cross(n, h)))


def read_heliostat_properties(path: str | Path) -> dict:
    """The raw properties mapping, checked for every key the kinematics needs."""
    src = str(path)
    data = _load_json(path, "heliostat properties")
    check_heliostat_properties(data, src)
    return data


def check_heliostat_properties(data: dict, src: str) -> None:
    """InputError naming the key when ``data`` lacks what :func:`kinematics_from_properties` reads."""
    _wgs84(_get(data, "heliostat_position", src), "heliostat_position", src)
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
    """One calibration record in the plant frame: the fit's :class:`Sample` (the spot of
    ``method``, UTIS unless asked otherwise), the target plane, the sun angles (azimuth
    clockwise from north, degrees) and every method's focal spot (m ENU)."""

    source: str
    sample: Sample
    target: TargetPlane
    sun_azimuth_deg: float
    sun_elevation_deg: float
    focal_spots: dict[str, np.ndarray]
    method: str | None = "UTIS"


def read_record(path: str | Path, towers: Towers, *, with_spot: bool = True,
                methods: tuple[str, ...] = ("UTIS",)) -> PaintRecord:
    """A calibration record. ``with_spot=False`` reads no focal spot (for a prediction, which
    must not see the measurement): ``sample.spot_enu`` is then NaN. ``methods``: the focal-spot
    methods the sample may take, in order of preference (the first the record has is used)."""
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
    if not SUN_AZIMUTH_DEG[0] <= paint_az <= SUN_AZIMUTH_DEG[1]:
        raise InputError(f"{src}: sun_azimuth {paint_az:g} is outside [{SUN_AZIMUTH_DEG[0]:g}, "
                         f"{SUN_AZIMUTH_DEG[1]:g}] degrees")
    sun_az = float(paint_azimuth_to_north(paint_az)) % 360.0
    if not 0.0 < sun_el <= 90.0:
        raise InputError(f"{src}: sun_elevation {sun_el} is not above the horizon")
    spots: dict[str, np.ndarray] = {}
    if with_spot:
        fs = _get(data, "focal_spot", src)
        for method in FOCAL_SPOT_METHODS:
            if isinstance(fs, dict) and method in fs:
                spots[method] = wgs84_to_enu(*_wgs84(fs[method], f"focal_spot.{method}", src),
                                             *towers.origin_wgs84)
                off = float(np.linalg.norm(spots[method] - target.center_enu))
                if off > MAX_SPOT_OFFSET_M:
                    raise InputError(f"{src}: focal_spot.{method} lies {off:.4g} m from target {name}'s "
                                     "centre (a measured spot is on its target: at most "
                                     f"{MAX_SPOT_OFFSET_M:g} m)")
    method = next((m for m in methods if m in spots), None)
    if with_spot and method is None:
        raise InputError(f"{src}: missing key 'focal_spot.{methods[0]}'"
                         + (f" (nor {', '.join(methods[1:])})" if len(methods) > 1 else ""))
    spot = spots[method] if method else np.full(3, np.nan)
    sample = Sample(azel_to_vector(sun_az, sun_el), az_steps, el_steps, spot)
    return PaintRecord(src, sample, target, sun_az, sun_el, spots, method)


def read_timestamps(path: str | Path) -> dict[str, str]:
    """A PAINT ``timestamps.json``: ``{"<heliostat>_<record id>": UTC time}``, each time ISO 8601
    with its offset (``Z``), returned as ISO 8601 UTC with milliseconds (the store's stamps)."""
    src = str(path)
    data = _load_json(path, "timestamps file")
    out = {}
    for key, value in data.items():
        try:
            t = datetime.fromisoformat(value.replace("Z", "+00:00")) if isinstance(value, str) else None
        except ValueError:
            t = None
        if t is None or t.tzinfo is None:
            raise InputError(f"{src}: {key}: expected an ISO 8601 time with its UTC offset, "
                             f"got {str(value)[:40]!r}")
        out[key] = t.astimezone(UTC).isoformat(timespec="milliseconds")
    return out


@dataclass(frozen=True)
class PaintSet:
    """The inputs of a fit on PAINT/ARTIST files: towers, the heliostat's id (from the
    properties file's name, ``<id>-heliostat-properties.json`` or ``<id>_properties.json``),
    properties, nominal kinematics, the records (each sample with its time when timestamps
    were given) and ``notes``: what the reading had to decide (a record measured by one
    method only, a record without a time)."""

    towers: Towers
    heliostat_id: str
    properties: dict
    kinematics: HeliostatKinematics
    records: list[PaintRecord]
    notes: tuple[str, ...] = ()


def heliostat_id_of(properties: str | Path) -> str:
    """The heliostat's id from its properties file's name: the part before the first - or _."""
    return re.split(r"[-_]", Path(properties).stem)[0]


def record_id_of(record: str | Path) -> str:
    """A PAINT record's id from its file name ``<id>_calibration_properties.json``."""
    return Path(record).name.split("_")[0]


def record_times(heliostat_id: str, records: list[str],
                 timestamps: dict[str, str]) -> tuple[list[float | None], list[str]]:
    """Each record's time, days since 1970 UTC, from PAINT ``timestamps`` (``"<heliostat>_<id>"``),
    and notes. A record missing from them is placed by its id between the records that have a
    time (PAINT ids rise with time), or has none when its id is not a number or no record
    around it has one."""
    days: list[float | None] = []
    for r in records:
        stamp = timestamps.get(f"{heliostat_id}_{record_id_of(r)}")
        days.append(None if stamp is None else datetime.fromisoformat(stamp).timestamp() / 86400.0)
    ids = [record_id_of(r) for r in records]
    known = [(int(i), d) for i, d in zip(ids, days, strict=True) if d is not None and is_ascii_index(i)]
    notes = []
    for k, (rid, d) in enumerate(zip(ids, days, strict=True)):
        if d is not None:
            continue
        if is_ascii_index(rid) and known:
            xs, ys = zip(*sorted(known), strict=True)
            days[k] = float(np.interp(int(rid), xs, ys))
            notes.append(f"{records[k]}: no time in the timestamps; placed by its id at "
                         f"{datetime.fromtimestamp(days[k] * 86400.0, UTC).isoformat(timespec='seconds')}")
        else:
            notes.append(f"{records[k]}: no time in the timestamps; counted with the newest records")
    return days, notes


def read_paint_set(records: list[str], properties: str | Path, towers: str | Path, *,
                   timestamps: dict[str, str] | None = None,
                   methods: tuple[str, ...] = ("UTIS",)) -> PaintSet:
    """Read and check every file of a fit (InputError naming the file and key); ``timestamps``
    (:func:`read_timestamps`) give each sample its time, ``methods`` the focal-spot methods a
    record may be measured by, in order of preference."""
    tw = read_towers(towers)
    props = read_heliostat_properties(properties)
    hid = heliostat_id_of(properties)
    kin = kinematics_from_properties(props, tw.origin_wgs84, hid)
    recs = [read_record(r, tw, methods=methods) for r in records]
    for r in recs:
        check_reach(r, kin)
    notes = [f"{r.source}: no {methods[0]} spot; {r.method}'s used" for r in recs if r.method != methods[0]]
    if timestamps is not None:
        days, time_notes = record_times(hid, records, timestamps)
        recs = [replace(r, sample=replace(r.sample, time_days=d)) for r, d in zip(recs, days, strict=True)]
        notes += time_notes
    return PaintSet(tw, hid, props, kin, recs, tuple(notes))
