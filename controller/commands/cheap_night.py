"""The product's planned night on a large simulated field with cheap optics
(:class:`simplant.cheap_night.CheapField`), with a budget of plant time.

The night is :class:`controller.calibration.night.planned.PlannedNight` — the same operation as
``heliocal campaign night`` — on a :class:`controller.calibration.campaign.field.Field` built from the
cheap field's devices. Without a plan it plans itself, as ``campaign night`` does (first
calibrating the heliostats that have no model); a plan handed in is stored first, so the
night runs it as it runs a resumed night's stored plan. The night ends when every pass is
done or when ``budget_s`` of plant time have passed: it is then stopped as the console's stop
would (beams parked, nothing further started). Used by ``benchmarks/bench_field.py`` and its
tests.

:func:`calibrate_from_truth` stands in for the calibration night (night 0) of a field too
large to calibrate closed loop in a benchmark: each heliostat's first capture of that night,
taken from the plant's truth, fitted by the product's model fit and recorded as night 0.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller.calibration.campaign.field import Field, PanelLamps
from controller.calibration.campaign.outcome import CampaignResult
from controller.calibration.cycle.pointing import steps_to_aim
from controller.calibration.night.passes import night_passes
from controller.calibration.night.planned import NightSummary, PlannedNight
from controller.calibration.night.planner import PlanItem, Unmeasurable
from controller.calibration.night.refit import refit_models
from controller.calibration.records import MeasurementRecord, RunRecord
from controller.commands.field import open_store
from controller.config import config_sha256
from controller.errors import LimitError
from controller.geometry.aiming import pointing_error_mrad, source_direction
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import vector_to_azel
from controller.storage.images import ImageArchive
from controller.storage.nights import NightBook

WATCH_S = 0.02  # wall seconds: the budget watcher's shortest wait, so at most WATCH_S x speedup plant s late
CONFIRM_S = 5.0  # plant seconds a lamp of the in-process panel may take to confirm


def watch_budget(cheap, end: float, done: threading.Event, stop: Callable[[], None], name: str
                 ) -> tuple[threading.Thread, threading.Event]:
    """Start a thread that calls ``stop()`` once ``cheap``'s plant clock reaches ``end`` (plant s),
    unless ``done`` is set first; returns it and the event it sets when it stopped the night. It
    waits the wall time the rest of the budget takes at the clock's fastest rate (``speedup``;
    at 1x or still it runs slower), at least :data:`WATCH_S`: one check every 20 ms woke it some
    two and a half times per measurement of a 10,000-heliostat night (issue 42)."""
    over = threading.Event()
    speedup = cheap.plant.clock.speedup

    def watch() -> None:
        while not done.wait(max(WATCH_S, (end - cheap.time.now()) / speedup)):
            if cheap.time.now() >= end:
                over.set()
                stop()
                return

    watcher = threading.Thread(target=watch, name=name, daemon=True)
    watcher.start()
    return watcher, over


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
    """The :class:`Field` of a cheap simulated field's devices, recording into ``store`` and its
    frames beside it (``images/``), as a real field's."""
    return Field(cheap.cfg, str(cheap.config_path), config_sha256(cheap.config_path), store, cheap.pool,
                 cheap.cameras, cheap.time, PanelLamps(cheap.lamps, cheap.time, CONFIRM_S),
                 images=ImageArchive(Path(store.path).parent / "images"),
                 meta={"plant": "simulated, cheap optics"})


def run_cheap_night(cheap, plan: list[PlanItem] | None, night: str, budget_s: float, *,
                    heliostat_ids: list[str] | None = None, unmeasurable: list[Unmeasurable] = (),
                    workers: int | None = None, unsafe_lamp_change: bool = False,
                    observers=()) -> CheapNight:
    """Run night ``night`` on ``cheap`` (module docstring): ``plan`` (None: planned by the night)
    for ``heliostat_ids`` (default: the plan's heliostats, or the whole field);
    ``unmeasurable``: what the planner said of the heliostats it left out of a plan handed in.
    ``unsafe_lamp_change`` lights each lamp without first making the heliostats safe for it
    (the defect the lamp change fixes, kept for its regression test); ``observers``: told what
    every campaign of the night does."""
    store = open_store(cheap.db_path)
    book = NightBook(store)
    done = threading.Event()
    try:
        plant = cheap_field(cheap, store)
        ids = heliostat_ids or (list(dict.fromkeys(i.heliostat_id for i in plan)) if plan is not None
                                else [h.id for h in cheap.cfg.heliostats])
        if plan is not None:
            book.record_plan(plan)
            book.open_night(night, "planned")
            book.add_to_summary(night, {"unmeasurable": [u.to_json() for u in unmeasurable]})
        pn = PlannedNight(plant, book, night, book.index_for(night), heliostat_ids=ids, workers=workers,
                          observers=observers)
        if unsafe_lamp_change:
            pn._change_lamp = lambda lamp, standbys: plant.lights_out()
        t0 = cheap.time.now()
        wall0 = time.perf_counter()
        watcher, over = watch_budget(cheap, t0 + budget_s, done, pn.request_stop, "night-budget")
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
    target = {p.name: p.target or cheap.cfg.calibration.target for p in night_passes(pn.plan, night)}
    per_target: dict[str, int] = {}
    for _, name in measured:
        per_target[target[name]] = per_target.get(target[name], 0) + 1
    beams = {tid: cam.beams_in_view for tid, cam in cheap.cameras.items()}
    return CheapNight(t1 - t0, time.perf_counter() - wall0, len(pn.plan), measured, results, beams,
                      over.is_set(), summary, per_target)


def calibrate_from_truth(cheap, name: str, *, noise_m: float = 0.02, seed: int = 0,
                         workers: int | None = None, heliostat_ids: list[str] | None = None) -> dict:
    """Night 0 of ``cheap`` without running it (module docstring): for every heliostat the pose
    the calibration cycle takes first (its nominal aim at the calibration target's centre under
    the calibration lamp, :func:`controller.calibration.cycle.pointing.steps_to_aim`), the spot the
    plant's truth puts on the target there (:meth:`CheapField.true_hit`) with ``noise_m`` of
    centroid noise per axis, the model the product fits to it
    (:func:`controller.calibration.night.refit.refit_models`), recorded as the calibration campaign
    and night 0 ``name`` (``heliostat_ids``: only these). Returns ``{"heliostats", "recorded",
    "unreachable", "fit_s", "record_s"}``."""
    cfg = cheap.cfg
    lamp, target = cfg.light_source(), cfg.target()
    lamp_pos = np.asarray(lamp.position_enu_m, float)
    centre = np.asarray(target.center_enu_m, float)
    u = np.cross([0.0, 0.0, 1.0], target.normal)
    u /= np.linalg.norm(u)
    v = np.cross(u, target.normal)
    rng = np.random.default_rng(seed)
    utc = cheap.time.utc()
    history: dict[str, list[MeasurementRecord]] = {}
    unreachable = []
    chosen = [cfg.heliostat(hid) for hid in heliostat_ids] if heliostat_ids is not None else cfg.heliostats
    for h in chosen:
        pos = np.asarray(h.position_enu_m, float)
        s = np.asarray(source_direction(lamp, pos), float)
        try:
            steps = steps_to_aim(HeliostatKinematics.from_config(h), None, s, centre, lamp_pos)
        except (LimitError, ValueError):
            unreachable.append(h.id)
            continue
        hit = cheap.true_hit(h.id, *steps, lamp.id, target.id)
        if hit is None:
            unreachable.append(h.id)
            continue
        spot = hit + rng.normal(0.0, noise_m) * u + rng.normal(0.0, noise_m) * v
        saz, sel = vector_to_azel(s)
        history[h.id] = [MeasurementRecord(
            1, int(steps[0]), int(steps[1]), tuple(float(c) for c in s), float(saz), float(sel),
            tuple(float(c) for c in centre), 0.0, centroid_enu=tuple(float(c) for c in spot),
            error_mrad=pointing_error_mrad(pos, centre, spot), measured_utc=utc,
            source_pos_enu=tuple(float(c) for c in lamp_pos))]
    fits = refit_models(cfg, history, workers=workers)
    t0 = time.perf_counter()
    store = open_store(cheap.db_path)
    try:
        book = NightBook(store)
        night, _ = book.open_night(name, "calibration")
        cid, _ = store.open_campaign(name, config_path=str(cheap.config_path),
                                     config_sha256=config_sha256(cheap.config_path), light_source=lamp.id,
                                     target=target.id, queue=[h.id for h in chosen],
                                     meta={"plant": "simulated, cheap optics",
                                           "night_0": "from the plant's truth"})
        for qi, (hid, ms) in enumerate(history.items()):
            store.record_run(cid, RunRecord(hid, qi, "calibrated", "done", 1, 0.0, 0.0,
                                            error_before_mrad=ms[0].error_mrad, measurements=ms,
                                            model=fits.models[hid]))
        store.finish_campaign(cid, "finished")
        book.finish_night(night.id, "finished", None, {"campaign": name, "status": "finished", "lamps": []})
    finally:
        store.close()
    return {"heliostats": len(chosen), "recorded": len(history), "unreachable": unreachable,
            "fit_s": fits.seconds, "record_s": time.perf_counter() - t0}
