"""One planned night of a large simulated field through the real runner, with cheap optics.

The product's night (:func:`controller.calibration.nights.run_night`: passes per lamp, the
targets of a lamp in parallel, each pass a :class:`controller.calibration.runner.Campaign`
with its state machine, target gate, fit and SQLite record store) runs against a
:class:`simplant.plant.SimulatedPlant` that is never started: its hidden heliostats are
driven in-process (:class:`simplant.inproc.InProcPool`) and seen by analytic-spot cameras
(:class:`simplant.cheap_camera.CheapCamera`), on the plant clock. The night ends when every
pass is done or when ``budget_s`` of plant time have passed (every running campaign is then
stopped as Ctrl-C would: beams parked, nothing further started). Used by
``benchmarks/bench_field.py`` and its test.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from controller.calibration.lamp_change import LampChanger, night_drives
from controller.calibration.nights import Pass, night_passes, run_night
from controller.calibration.planner import PlanItem
from controller.calibration.runner import Campaign, CampaignObserver, CampaignOptions, CampaignResult
from controller.config import config_sha256
from controller.storage.db import CampaignStore
from simplant.cheap_camera import BeamField, CheapCamera
from simplant.harness import LampSwitch
from simplant.inproc import InProcPool
from simplant.plant import SimulatedPlant
from simplant.settings import SimulationSettings

WATCH_S = 0.02  # wall seconds between checks of the night's budget
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


@dataclass
class CheapNight:
    """What one night did: ``plant_s`` of plant time and ``wall_s`` of wall time, the
    measurements recorded (``measured``: (heliostat, pass) pairs) and every capture's beams
    in view per target camera (the simulated truth of "one beam per target")."""

    plant_s: float
    wall_s: float
    planned: int
    measured: list[tuple[str, str]]
    results: list[CampaignResult]
    beams_in_view: dict[str, list[tuple[str, ...]]]
    stopped_by_budget: bool
    per_target: dict[str, int] = field(default_factory=dict)

    @property
    def heliostats(self) -> set[str]:
        return {hid for hid, _ in self.measured}


class _Setup(CampaignObserver):
    """Plant time at 1x from its creation until the campaign has started (its setup: drive
    readings, pointing and queue of every heliostat of the pass, opening the campaign):
    the controller's computing, like ``Campaign(compute=...)`` for the measurement chain. At
    a large speedup the wall seconds of setting up a pass of hundreds of heliostats would
    otherwise pass as plant hours."""

    def __init__(self, realtime) -> None:
        self._cm = realtime
        self._cm.__enter__()
        self._open = True

    def campaign_started(self, campaign_id: int, queue: list[str], done: set[str]) -> None:
        self.end()

    def end(self) -> None:
        if self._open:
            self._open = False
            self._cm.__exit__(None, None, None)


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
        self.db_path = out / "night.db"

    def run_night(self, plan: list[PlanItem], night: str, budget_s: float, *,
                  change_lamp: bool = True) -> CheapNight:
        """Run ``plan`` as night ``night`` (module docstring). ``change_lamp=False`` lights each
        lamp without first making the heliostats safe for it (the defect the lamp change fixes,
        kept for its regression test)."""
        cfg, plant = self.cfg, self.plant
        cal = cfg.calibration
        sha = config_sha256(self.config_path)
        store = CampaignStore(self.db_path)
        store.campaign_lock.acquire()  # once, before the targets' campaigns open theirs in parallel
        live: set[Campaign] = set()
        lock = threading.Lock()
        over = threading.Event()

        def run_pass(p: Pass) -> CampaignResult:
            tid = p.target or cal.target
            setup = _Setup(plant.clock.realtime())
            c = Campaign(cfg, str(self.config_path), store, self.pool, self.cameras[tid], config_sha256=sha,
                         heliostat_ids=list(p.aims),
                         options=CampaignOptions(name=p.name, light_source=p.lamp, aims=p.aims, observe=True,
                                                 pipeline_depth=cal.pipeline_depth, settle_s=cal.settle_s,
                                                 target=p.target),
                         clock=plant.clock, sleep=plant.clock.sleep, compute=plant.clock.realtime,
                         utc=plant.utc, meta={"plant": "simulated, cheap optics"},
                         observers=[LampSwitch(plant, tid), setup])
            with lock:
                live.add(c)
                if over.is_set():  # the night is over: the pass records itself interrupted
                    c.request_stop()
            try:
                return c.run()
            finally:
                setup.end()
                with lock:
                    live.discard(c)

        def stop_all() -> None:
            with lock:
                for c in list(live):
                    c.request_stop()

        done = threading.Event()

        def watch() -> None:
            while not done.wait(WATCH_S):
                if plant.clock() >= t0 + budget_s:
                    over.set()
                    stop_all()
                    return

        wall0 = time.perf_counter()
        t0 = plant.clock()
        watcher = threading.Thread(target=watch, name="night-budget", daemon=True)
        watcher.start()
        try:
            changer = LampChanger(cfg, night_drives(cfg, self.pool), store.latest_model, plant.lights_out,
                                  clock=plant.clock, sleep=plant.clock.sleep, compute=plant.clock.realtime)
            results = run_night(plan, night, run_pass, stop_all, changer if change_lamp else None)
        finally:
            done.set()
            watcher.join()
            t1 = plant.clock()
            store.close()
        measured = [(run.heliostat_id, r.name) for r in results for run in r.runs if run.status == "measured"]
        per_target: dict[str, int] = {}
        names = {p.name: p.target or cal.target for p in night_passes(plan, night)}
        for _, name in measured:
            per_target[names[name]] = per_target.get(names[name], 0) + 1
        beams = {tid: cam.beams_in_view for tid, cam in self.cameras.items()}
        return CheapNight(t1 - t0, time.perf_counter() - wall0, len(plan), measured, results, beams,
                          over.is_set(), per_target)

