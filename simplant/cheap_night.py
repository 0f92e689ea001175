"""A large simulated field with cheap optics: the devices of a planned night at field scale.

:class:`CheapField` is a :class:`simplant.plant.SimulatedPlant` that is never started: its
hidden heliostats are driven in-process (:class:`simplant.inproc.InProcPool`), seen by
analytic-spot cameras (:class:`simplant.cheap_camera.CheapCamera`) and lit through an
in-process lamp panel (:class:`simplant.inproc.InProcLampPanel`), on the plant clock. The
product's night runs on it (``controller.commands._cheap_night``), as it runs on any field.
Used by ``benchmarks/bench_field.py`` and its tests.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import yaml

from controller.devices.plant_time import PlantTime
from simplant.cheap_camera import BeamField, CheapCamera
from simplant.inproc import InProcLampPanel, InProcPool
from simplant.plant import SimulatedPlant
from simplant.settings import SimulationSettings

TARGET_HEIGHTS = (40.0, 30.0, 20.0)  # m: upper, middle, lower target on the tower
LAMPS = ([0.0, 5.0, 60.0], [-60.0, 30.0, 25.0], [60.0, 30.0, 25.0], [0.0, 3.0, 8.0],
         [-200.0, 40.0, 40.0], [200.0, 40.0, 40.0])
CAMERA_PX = (128, 96)  # width, height: the cheap camera's rectified view


def field_data(base: dict, n: int, targets: int, geometries: int = 3) -> dict:
    """A field of ``n`` heliostats (config mapping) from ``base`` (a plant config mapping whose
    first heliostat is the prototype): staggered half rings north of the tower from 40 m, 7 m
    apart, heliostats 6 m apart on a ring, each focused at its range to the tower, 30 per
    serial bus; ``targets`` targets on the
    tower (``calibration.targets``, 2 × 2 aim grid), six lamps, the planner at ``geometries``
    per heliostat, standby points 12 m off the aim; a ``CAMERA_PX`` camera without
    registration (cheap optics)."""
    proto = base["heliostats"][0]
    data = copy.deepcopy(base)
    data["targets"] = [{"id": f"T{k + 1}", "center_enu_m": [0.0, 0.0, h], "normal": [0.0, 1.0, 0.0],
                        "width_m": 8.0, "height_m": 7.0} for k, h in enumerate(TARGET_HEIGHTS[:targets])]
    data["camera"] = {**{k: v for k, v in data["camera"].items() if k != "registration"},
                      "width_px": CAMERA_PX[0], "height_px": CAMERA_PX[1], "crf_file": None}
    data["light_sources"] = [{"kind": "sun", "id": "sun", "angular_diameter_mrad": 9.3}] + [
        {"kind": "lamp", "id": f"L{i + 1}", "position_enu_m": p, "diameter_m": 0.3}
        for i, p in enumerate(LAMPS)]
    cal = data["calibration"]
    cal.update(light_source="L1", target="T1", targets=[f"T{k + 1}" for k in range(targets)],
               lamps=[f"L{i + 1}" for i in range(len(LAMPS))],
               aim_grid={"rows": 2, "cols": 2, "margin_m": 2.5},
               # Oblique beams from the field's wings are wide (up to ~0.7 m σ on the target):
               # their standby points must leave the view by more than a spot.
               standby_offset_m=12.0,
               planner={"geometries_per_night": geometries, "check_geometries": 1, "sun_positions": 16})
    hs, r, k = [], 40.0, 0
    while len(hs) < n:
        count = int(2 * math.pi * r / 2 / 6.0)  # half a ring, 6 m apart
        for j in range(min(count, n - len(hs))):
            az = math.radians(-70.0 + 140.0 * (j + 0.5 * (k % 2)) / count)
            h = copy.deepcopy(proto)
            h["id"] = f"F{len(hs) + 1:04d}"
            h["position_enu_m"] = [round(r * math.sin(az), 2), round(r * math.cos(az), 2), 2.0]
            # Focused at its slant range to the middle of the tower's targets, as a field's
            # heliostats are (the prototype's focus would blur the far rows over the whole view).
            h["mirror"] = {**proto["mirror"], "focal_length_m": round(math.hypot(r, 30.0 - 2.0), 1)}
            h["link"] = {"kind": "serial", "device": f"/dev/heliocal-bus{len(hs) // 30}",
                         "address": 1 + len(hs) % 30}
            hs.append(h)
        r += 7.0
        k += 1
    data["heliostats"] = hs
    return data


class CheapField:
    """The unstarted plant of ``data`` (a config mapping) in ``out``, its in-process drives and
    one cheap camera per target (:mod:`simplant.cheap_night`)."""

    def __init__(self, data: dict, out: Path, *, speedup: float = 1000.0, seed: int = 0) -> None:
        out.mkdir(parents=True, exist_ok=True)
        self.config_path = out / "field.yaml"
        self.config_path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        self.plant = SimulatedPlant(data, out / "plant", settings=SimulationSettings(clock_speedup=speedup,
                                                                                     seed=seed),
                                    source=str(self.config_path))
        self.cfg = self.plant.cfg
        self.beams = BeamField(self.plant)
        self.cameras = {t.id: CheapCamera(self.plant, self.beams, self.cfg.for_target(t.id), seed=seed + k)
                        for k, t in enumerate(self.cfg.targets)}
        self.pool = InProcPool.for_plant(self.plant)
        self.lamps = InProcLampPanel(self.plant)
        self.time = PlantTime(now=self.plant.clock, sleep=self.plant.clock.sleep, utc=self.plant.utc,
                              computing=self.plant.clock.realtime)
        self.db_path = out / "night.db"
