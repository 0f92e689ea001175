"""The plant configuration of a field known only by its PAINT files (``heliocal import paint``
without ``--config``, docs/import.md).

What PAINT holds is copied; what it does not hold is stated, never guessed silently:

* ``site``: the towers file's ``power_plant_properties`` (origin of the ENU frame, its ``ID``
  as the name); pressure from the altitude by the standard atmosphere,
  p = 1013.25 mbar · exp(−h / 8434.5 m); 15 °C;
* ``targets``: every target of the towers file, its size the spread of its surveyed points
  (:func:`controller.geometry.paint_io.plane_extent`);
* ``light_sources``: the sun (PAINT's records are daytime sun calibrations);
* ``heliostats``: position, mirror size and concentrator translation from each properties
  file; ``actuators[0]`` is the elevation axis, ``actuators[1]`` azimuth, with PAINT's names
  and units; soft limits are the actuator's increment range, narrowed to where its stroke closes
  the actuator triangle (:func:`soft_limits`); the focal length is the slant range to the
  calibration target (PAINT's mirrors are canted on the receiver); ``link: none`` (PAINT knows
  no links: nothing can be driven until they are written in);
* ``camera``: two sensors and no driver — PAINT holds no camera; a campaign needs one written in;
* ``calibration``: the sun on the target most of the records were taken on.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import yaml
from pydantic import ValidationError

from controller.config import Heliostat
from controller.errors import InputError
from controller.geometry.frames import wgs84_to_enu
from controller.geometry.paint_io import Towers

SCALE_HEIGHT_M = 8434.5  # standard atmosphere, isothermal scale height at 15 °C


@dataclass(frozen=True)
class FieldConfig:
    """The configuration document (:func:`field_document`), the heliostats left out of it
    (id -> why: the product cannot represent them) and a note per heliostat whose soft limits
    were narrowed."""

    document: dict
    refused: dict[str, str]
    notes: dict[str, str]

    def yaml_text(self) -> str:
        """The document as YAML, headed by where it came from and what must be written in (the
        same folder gives the same bytes, wherever it lies)."""
        head = ("# Field configuration written by `heliocal import paint` from a PAINT folder\n"
                "# (docs/import.md). PAINT holds no links and no camera: every heliostat has\n"
                "# `link: none` (nothing can drive it) and the camera has no driver; write them\n"
                "# in before a campaign. Axis keys and units are PAINT/ARTIST's.\n")
        return head + yaml.safe_dump(self.document, sort_keys=False, default_flow_style=None, width=110)


def soft_limits(actuator: dict) -> tuple[int, int]:
    """The steps [lo, hi] inside the increment range [min_increment, max_increment] where the
    stroke L = s / increment + L₀ stays inside the actuator triangle |o − r| ≤ L ≤ o + r
    (controller.geometry.actuators, Eq. 1-2), one step in from its edges; lo ≥ hi when none."""
    inc, l0 = float(actuator["increment"]), float(actuator["initial_stroke_length"])
    o, r = float(actuator["offset"]), float(actuator["pivot_radius"])
    lo = max(int(math.ceil(actuator["min_increment"])), math.floor((abs(o - r) - l0) * inc) + 1)
    hi = min(int(math.floor(actuator["max_increment"])), math.ceil((o + r - l0) * inc) - 1)
    return lo, hi


def _axis(actuator: dict) -> dict:
    lo, hi = soft_limits(actuator)
    return {"increment": float(actuator["increment"]),
            "initial_stroke_length": float(actuator["initial_stroke_length"]),
            "offset": float(actuator["offset"]), "pivot_radius": float(actuator["pivot_radius"]),
            "initial_angle": float(actuator["initial_angle"]),
            "clockwise_axis_movement": bool(actuator["clockwise_axis_movement"]),
            "min_increment": int(math.ceil(actuator["min_increment"])),
            "max_increment": int(math.floor(actuator["max_increment"])),
            "soft_limits": {"min_steps": lo, "max_steps": hi}}


def _size(props: dict, key: str, src: str) -> float:
    v = props.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise InputError(f"{src}: {key} (the mirror's size, m) must be a number > 0, got {v!r}")
    return round(float(v), 4)


def heliostat_entry(hid: str, props: dict, src: str, origin, aim_enu) -> dict:
    """The ``heliostats[]`` entry of one checked PAINT properties mapping (module docstring)."""
    kp = props["kinematics_properties"]
    pos = wgs84_to_enu(*props["heliostat_position"], *origin)
    conc = [round(float(kp.get(f"concentrator_translation_{a}", 0.0)), 6) for a in "enu"]
    return {"id": hid, "position_enu_m": [round(float(v), 4) for v in pos],
            "mirror": {"width_m": _size(props, "width", src), "height_m": _size(props, "height", src),
                       "focal_length_m": round(float(np.linalg.norm(np.asarray(aim_enu) - pos)), 1)},
            "axes": {"azimuth": _axis(kp["actuators"][1]), "elevation": _axis(kp["actuators"][0])},
            "link": {"kind": "none"}, "concentrator_translation_m": conc}


def field_document(towers: Towers, properties: dict[str, tuple[str, dict]], targets_used: Counter
                   ) -> FieldConfig:
    """The configuration of the heliostats ``properties`` (id -> (file, checked mapping)) and the
    targets of ``towers``; the calibration target is the one most used (``targets_used``: target
    name -> records, ties to the first in the file). A heliostat the schema refuses, or whose
    stroke leaves the actuator triangle over its whole range, is left out (``refused``)."""
    lat, lon, alt = towers.origin_wgs84
    main = max(towers.targets, key=lambda t: (targets_used.get(t, 0), -list(towers.targets).index(t)))
    targets = []
    for t in towers.targets.values():
        if t.size_m is None:
            raise InputError(f"towers file: {t.name}.coordinates: only a centre is surveyed; the target's "
                             "size is unknown")
        targets.append({"id": t.name, "center_enu_m": [round(float(v), 4) for v in t.center_enu],
                        "normal": [round(float(v), 8) for v in t.normal],
                        "width_m": round(t.size_m[0], 3), "height_m": round(t.size_m[1], 3)})
    helios, refused, notes = [], {}, {}
    for hid, (src, props) in sorted(properties.items()):
        entry = heliostat_entry(hid, props, src, towers.origin_wgs84, towers.targets[main].center_enu)
        narrowed, empty = [], []
        for name, index in (("elevation", 0), ("azimuth", 1)):
            axis = entry["axes"][name]
            lo, hi = axis["soft_limits"]["min_steps"], axis["soft_limits"]["max_steps"]
            if lo >= hi:
                empty.append(f"actuators[{index}] ({name})")
            elif (lo, hi) != (axis["min_increment"], axis["max_increment"]):
                narrowed.append(f"actuators[{index}] ({name}): soft limits [{lo}, {hi}] of the increment "
                                f"range [{axis['min_increment']}, {axis['max_increment']}]: beyond, the "
                                "stroke leaves the actuator triangle")
        if empty:
            refused[hid] = (f"{src}: {' and '.join(empty)}: the stroke leaves the actuator triangle over the "
                            "whole increment range (initial_stroke_length, offset, pivot_radius)")
            continue
        try:
            Heliostat.model_validate(entry)
        except ValidationError as exc:
            err = exc.errors()[0]
            where = ".".join(str(p) for p in err["loc"])
            refused[hid] = f"{src}: {where}: {err['msg'].removeprefix('Value error, ')}"
            continue
        if narrowed:
            notes[hid] = f"{src}: " + "; ".join(narrowed)
        helios.append(entry)
    doc = {"site": {"name": towers.plant_id or "PAINT field", "latitude_deg": lat, "longitude_deg": lon,
                    "elevation_m": alt, "pressure_mbar": round(1013.25 * math.exp(-alt / SCALE_HEIGHT_M), 1),
                    "temperature_c": 15.0},
           "targets": targets, "light_sources": [{"kind": "sun", "id": "sun"}],
           "heliostats": helios,
           "camera": {"sensors": [{"name": "low", "exposure_s": 0.001},
                                  {"name": "high", "exposure_s": 0.01}]},
           "calibration": {"light_source": "sun", "target": main}}
    return FieldConfig(doc, refused, notes)
