"""A large simulated field with cheap optics: the devices of a planned night at field scale.

:class:`CheapField` is a :class:`simplant.plant.SimulatedPlant` that is never started: its
hidden heliostats are driven in-process (:class:`simplant.devices.inproc.InProcPool`), seen by
analytic-spot cameras (:class:`simplant.devices.cheap_camera.CheapCamera`) and lit through an
in-process lamp panel (:class:`simplant.devices.inproc.InProcLampPanel`), on the plant clock. The
product's night runs on it (``controller.commands.cheap_night``), as it runs on any field.
Used by ``benchmarks/bench_field.py`` and its tests.
"""

from __future__ import annotations

import copy
import csv
import json
import math
from pathlib import Path

import numpy as np
import yaml

from controller.config import load_config
from controller.devices.plant_time import PlantTime
from simplant.devices.cheap_camera import BeamField, CheapCamera
from simplant.devices.inproc import InProcLampPanel, InProcPool
from simplant.plant import SimulatedPlant
from simplant.settings import SimulationSettings

LOWEST_TARGET_M = 20.0  # m: centre of the lowest target on the tower
TARGET_GAP_M = 3.0  # m between stacked targets
LAMPS = ([0.0, 5.0, 60.0], [-60.0, 30.0, 25.0], [60.0, 30.0, 25.0], [0.0, 3.0, 8.0],
         [-200.0, 40.0, 40.0], [200.0, 40.0, 40.0])
CAMERA_PX = (128, 96)  # width, height: the cheap camera's rectified view
SPAN_DEG = 50.0  # the rings span ±this from north: the prototype's azimuth reaches the tower from there
AIM_OFFSET_V_M = 1.0  # the aim grid's points are this far above and below the target's centre
# Room a target leaves, per side, beyond the 3σ spot of the farthest heliostat aimed at it: the
# aim offset, the uncertainty of a spot's position after the calibration night, the margin.
TARGET_ROOM_M = 2.7


def field_data(base: dict, n: int, targets: int, geometries: int = 3, span_deg: float = SPAN_DEG,
               beams: int = 1) -> dict:
    """A field of ``n`` heliostats (config mapping) from ``base`` (a plant config mapping whose
    first heliostat is the prototype): staggered half rings north of the tower from 40 m, 7 m
    apart, spanning ±``span_deg``, heliostats 6 m apart on a ring, each focused at its
    range to the tower, 30 per serial bus; ``targets`` targets stacked on the tower
    (``calibration.targets``, 2 × 2 aim grid :data:`AIM_OFFSET_V_M` above and below the centre),
    sized for the field: a target is tall enough for the 3σ spot of the farthest heliostat
    (σ = 2 × slope error × range, Eq. 1 of :mod:`controller.geometry.spot`) plus
    :data:`TARGET_ROOM_M` per side, at least 7 m, and 8/7 as wide; six lamps (the tower's top
    lamp above the highest target), the planner at ``geometries`` per heliostat, standby
    points at least 12 m off the aim; a ``CAMERA_PX`` camera without registration (cheap
    optics). ``beams`` > 1 (``calibration.beams_per_target``): each target holds a grid of
    ⌈√beams⌉ columns of such spots, one per slot (controller.calibration.beams.slots), and is that
    many spot-heights tall and wide."""
    proto = base["heliostats"][0]
    data = copy.deepcopy(base)
    positions, r, k = [], 40.0, 0
    while len(positions) < n:
        count = int(2 * math.pi * r * (2 * span_deg / 360.0) / 6.0)  # 6 m apart along the ring
        for j in range(min(count, n - len(positions))):
            az = math.radians(-span_deg + 2 * span_deg * (j + 0.5 * (k % 2)) / count)
            positions.append((r, az))
        r += 7.0
        k += 1
    far = max(rr for rr, _ in positions)
    slope = 1e-3 * float(proto["mirror"].get("slope_error_mrad", 1.5))
    cols = math.ceil(math.sqrt(beams))
    rows = math.ceil(beams / cols)
    height = rows * max(7.0, 2.0 * (3.0 * 2.0 * slope * far + TARGET_ROOM_M))
    width = 8.0 / 7.0 * height * cols / rows
    step = height + TARGET_GAP_M
    heights = [LOWEST_TARGET_M + (2 - i) * step for i in range(3)][:targets]
    middle = LOWEST_TARGET_M + step
    data["targets"] = [{"id": f"T{i + 1}", "center_enu_m": [0.0, 0.0, round(h, 2)], "normal": [0.0, 1.0, 0.0],
                        "width_m": round(width, 2), "height_m": round(height, 2)}
                       for i, h in enumerate(heights)]
    data["camera"] = {**{k: v for k, v in data["camera"].items() if k != "registration"},
                      "width_px": CAMERA_PX[0], "height_px": CAMERA_PX[1], "crf_file": None}
    lamps = [list(p) for p in LAMPS]
    lamps[0][2] = max(lamps[0][2], LOWEST_TARGET_M + 2 * step + height / 2 + 10.0)  # above the highest target
    data["light_sources"] = [{"kind": "sun", "id": "sun", "angular_diameter_mrad": 9.3}] + [
        {"kind": "lamp", "id": f"L{i + 1}", "position_enu_m": p, "diameter_m": 0.3}
        for i, p in enumerate(lamps)]
    cal = data["calibration"]
    cal.update(beams_per_target=beams, light_source="L1", target="T1",
               targets=[f"T{i + 1}" for i in range(targets)],
               lamps=[f"L{i + 1}" for i in range(len(LAMPS))],
               aim_grid={"rows": 2, "cols": 2, "margin_m": round(height / 2 - AIM_OFFSET_V_M, 2)},
               # The least standby offset; the cycle grows it with the spot's size (oblique beams
               # from the field's wings are wide) so that a parked spot stays out of every view.
               standby_offset_m=12.0,
               planner={"geometries_per_night": geometries, "check_geometries": 1, "sun_positions": 16})
    hs = []
    for i, (rr, az) in enumerate(positions):
        h = copy.deepcopy(proto)
        h["id"] = f"F{i + 1:05d}" if n > 9999 else f"F{i + 1:04d}"
        h["position_enu_m"] = [round(rr * math.sin(az), 2), round(rr * math.cos(az), 2), 2.0]
        # Focused at its slant range to the middle target, as a field's heliostats are (the
        # prototype's focus would blur the far rows over the whole view).
        h["mirror"] = {**proto["mirror"], "focal_length_m": round(math.hypot(rr, middle - 2.0), 1)}
        h["link"] = {"kind": "serial", "device": f"/dev/heliocal-bus{i // 30}", "address": 1 + i % 30}
        hs.append(h)
    data["heliostats"] = hs
    return data


def write_config(data: dict, path: Path) -> None:
    """Write config mapping ``data`` to ``path`` as a plant with a large field keeps it: its
    heliostats in ``<stem>.csv`` beside it (the configuration's ``field`` section: a design per
    distinct mirror and axes, the focal length per row, a bus per link without its station)."""
    designs: dict[str, str] = {}
    buses: dict[str, str] = {}
    spec: dict = {"file": f"{path.stem}.csv", "kinematics": {}, "buses": {}}
    rows = []
    for h in data["heliostats"]:
        mirror = {k: v for k, v in h["mirror"].items() if k != "focal_length_m"}
        design = json.dumps([mirror, h["axes"]], sort_keys=True)
        if design not in designs:
            designs[design] = f"design{len(designs) + 1}"
            spec["kinematics"][designs[design]] = {"mirror": {**h["mirror"]}, "axes": h["axes"]}
        link = {k: v for k, v in h["link"].items() if k not in ("address", "unit")}
        bus = json.dumps(link, sort_keys=True)
        if bus not in buses:
            buses[bus] = f"bus{len(buses) + 1}"
            spec["buses"][buses[bus]] = link
        station = h["link"].get("address", h["link"].get("unit"))
        rows.append([h["id"], *h["position_enu_m"], designs[design], buses[bus], station,
                     h["mirror"]["focal_length_m"]])
    with open(path.with_suffix(".csv"), "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["id", "east_m", "north_m", "up_m", "kinematics", "bus", "station", "focal_length_m"])
        w.writerows(rows)
    rest = {k: v for k, v in data.items() if k != "heliostats" and not str(k).startswith("x-")}
    path.write_text(yaml.safe_dump({**rest, "field": spec}, sort_keys=False), encoding="utf-8")


class CheapField:
    """The unstarted plant of ``data`` (a config mapping) in ``out``, its in-process drives and
    one cheap camera per target (:mod:`simplant.cheap_night`)."""

    def __init__(self, data: dict, out: Path, *, speedup: float = 1000.0, seed: int = 0) -> None:
        out.mkdir(parents=True, exist_ok=True)
        self.config_path = out / "field.yaml"
        write_config(data, self.config_path)
        self.plant = SimulatedPlant(data, out / "plant", settings=SimulationSettings(clock_speedup=speedup,
                                                                                     seed=seed),
                                    source=str(self.config_path))
        # The product reads the field as a plant keeps it: its configuration and field file.
        self.cfg = load_config(self.config_path)
        self.beams = BeamField(self.plant)
        self.cameras = {t.id: CheapCamera(self.plant, self.beams, self.cfg.for_target(t.id), seed=seed + k)
                        for k, t in enumerate(self.cfg.targets)}
        self.pool = InProcPool.for_plant(self.plant, touched=self.beams.touch)
        self.lamps = InProcLampPanel(self.plant)
        self.time = PlantTime(now=self.plant.clock, sleep=self.plant.clock.sleep, utc=self.plant.utc,
                              computing=self.plant.clock.realtime)
        self.db_path = out / "night.db"

    def true_hit(self, hid: str, az_steps: float, el_steps: float, lamp: str,
                 target: str) -> np.ndarray | None:
        """Where the hidden heliostat's beam under ``lamp`` lands on ``target``'s plane at the
        given steps tonight (m ENU; None when it does not meet the plane): the plant's truth, as
        the cheap camera draws it (:class:`simplant.devices.cheap_camera.BeamField`)."""
        n = self.plant.true_normal_at(hid, az_steps, el_steps)
        c = self.plant.true_mirror_center(hid, az_steps, el_steps)
        s = np.asarray(self.cfg.light_source(lamp).position_enu_m, float) - c
        s /= np.linalg.norm(s)
        beam = 2.0 * float(s @ n) * n - s
        t = self.cfg.target(target)
        p0, nn = np.asarray(t.center_enu_m, float), np.asarray(t.normal, float)
        denom = float(beam @ nn)
        if abs(denom) < 1e-12 or float((p0 - c) @ nn) / denom <= 0:
            return None
        return c + float((p0 - c) @ nn) / denom * beam
