"""The product's planned night on a large simulated field with cheap optics
(:class:`simplant.cheap_night.CheapField`), with a budget of plant time.

The night is :class:`controller.calibration.night.PlannedNight` — the same operation as
``heliocal campaign night`` — on a :class:`controller.calibration.field.Field` built from the
cheap field's devices. A plan handed in is stored first, so the night runs it as it runs a
resumed night's stored plan. The night ends when every pass is done or when ``budget_s`` of
plant time have passed: it is then stopped as the console's stop would (beams parked,
nothing further started). Used by ``benchmarks/bench_field.py`` and its tests.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from controller.calibration.field import Field, PanelLamps
from controller.calibration.night import NightSummary, PlannedNight
from controller.calibration.nights import night_passes
from controller.calibration.outcome import CampaignResult
from controller.calibration.planner import PlanItem
from controller.commands._field import open_store
from controller.config import config_sha256
from controller.storage.nights import NightBook

WATCH_S = 0.02  # wall seconds between checks of the night's budget
CONFIRM_S = 5.0  # plant seconds a lamp of the in-process panel may take to confirm


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
    summary: NightSummary
    per_target: dict[str, int] = field(default_factory=dict)

    @property
    def heliostats(self) -> set[str]:
        return {hid for hid, _ in self.measured}


def cheap_field(cheap, store) -> Field:
    """The :class:`Field` of a cheap simulated field's devices, recording into ``store``."""
    return Field(cheap.cfg, str(cheap.config_path), config_sha256(cheap.config_path), store, cheap.pool,
                 cheap.cameras, cheap.time, PanelLamps(cheap.lamps, cheap.time, CONFIRM_S),
                 meta={"plant": "simulated, cheap optics"})


def run_cheap_night(cheap, plan: list[PlanItem], night: str, budget_s: float, *,
                    unsafe_lamp_change: bool = False) -> CheapNight:
    """Run ``plan`` as night ``night`` on ``cheap`` (module docstring). ``unsafe_lamp_change``
    lights each lamp without first making the heliostats safe for it (the defect the lamp
    change fixes, kept for its regression test)."""
    store = open_store(cheap.db_path)
    book = NightBook(store)
    over = threading.Event()
    done = threading.Event()
    try:
        plant = cheap_field(cheap, store)
        book.record_plan(plan)
        pn = PlannedNight(plant, book, night, book.index_for(night),
                          heliostat_ids=list(dict.fromkeys(i.heliostat_id for i in plan)))
        if unsafe_lamp_change:
            pn._change_lamp = lambda lamp, standbys: plant.lights_out()
        t0 = cheap.time.now()

        def watch() -> None:
            while not done.wait(WATCH_S):
                if cheap.time.now() >= t0 + budget_s:
                    over.set()
                    pn.request_stop()
                    return

        wall0 = time.perf_counter()
        watcher = threading.Thread(target=watch, name="night-budget", daemon=True)
        watcher.start()
        try:
            summary = pn.run()
        finally:
            done.set()
            watcher.join()
            t1 = cheap.time.now()
    finally:
        store.close()
    results = pn.results
    measured = [(run.heliostat_id, r.name) for r in results for run in r.runs if run.status == "measured"]
    target = {p.name: p.target or cheap.cfg.calibration.target for p in night_passes(plan, night)}
    per_target: dict[str, int] = {}
    for _, name in measured:
        per_target[target[name]] = per_target.get(target[name], 0) + 1
    beams = {tid: cam.beams_in_view for tid, cam in cheap.cameras.items()}
    return CheapNight(t1 - t0, time.perf_counter() - wall0, len(plan), measured, results, beams,
                      over.is_set(), summary, per_target)
