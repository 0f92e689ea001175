"""A planned night of a large field through the product's own night, at 1,000 or 10,000 heliostats.

The field (:func:`simplant.cheap_night.field_data`): heliostats on staggered half rings north
of the tower (from 40 m, ±50°), each with the demo's AA39 actuators and focused at its range;
``--targets`` targets stacked on the tower, each with its camera and a 2 × 2 aim grid, sized so
that the farthest heliostat's spot fits; six lamps. Its devices are in-process
(:class:`simplant.cheap_night.CheapField`: the firmware physics without a wire, analytic-spot
cameras of 128 × 96 pixels, an in-process lamp panel) on the plant clock at ``--speedup``.

What runs, in order, each timed:

1. **night 0** (``seed_s``): the calibration night, made from the plant's truth rather than
   run closed loop (10,000 closed-loop runs would take hours of wall time): each heliostat's
   first capture at the calibration lamp, fitted by the product's model fit
   (:func:`controller.commands.cheap_night.calibrate_from_truth`);
2. **planning** (``plan_s``): tonight's plan for the *whole* field from the models in the
   database (:func:`controller.calibration.night.planner.plan_field`, as ``PlannedNight`` plans:
   measurable geometries only, ``--workers`` processes); ``planner_ms_per_decision`` is its wall
   time per heliostat planned (one decision = one heliostat's geometries);
3. **the night** (``night_wall_s``, ``plant_hours``): the product's night operation
   (:func:`controller.commands.cheap_night.run_cheap_night` →
   :class:`controller.calibration.night.planned.PlannedNight`: lamp changes in the dark for every
   heliostat of the field, one campaign per pass, the targets of a lamp in parallel, the
   state machine, gate, fit, SQLite store, frame archive) over the whole field. When the plan
   has more than ``--sample`` geometries, the night runs the plan of an evenly spread sample of
   heliostats (every k-th, so every ring and target is in it) — the rest of the plan is made
   and counted, not run: 30,000 measurements do not fit 30 minutes of wall time. ``planned``
   and ``measured`` are the sample's; ``plan_total`` the whole field's;
4. **refit** (``fit_s``): every heliostat's model refitted on all its measurements
   (:func:`controller.calibration.night.refit.refit_models`, ``heliocal model refit``), in
   ``--workers`` processes; ``fit_same_as_serial`` checks 20 of them against a fit one at a
   time in this process;
5. **morning report** (``report_s``): :func:`controller.reports.night.write_night_report` of the
   night, for every heliostat of the field.

``second_beam_captures``: captures in which a target's camera saw more than one beam (the
simulated truth: :attr:`simplant.devices.cheap_camera.CheapCamera.beams_in_view`), or a beam
not the capture's; ``second_beam_heliostats``: for the 20 heliostats seen most often where
their beam was not meant to be, per target — captures, first and last plant second, the lamp,
the targets their plan gives them under it, the states their cycle was in at those captures,
where the beam hit first, the rods' true steps then and the heliostat's last recorded run
(:meth:`controller.commands.sim.field.OnTarget.note_strays`).
``measured_elsewhere``: measurements whose centroid lies more than 1 m from every true hit of
their own heliostat's beam in the recent captures — a spot credited to another beam, or none
(:meth:`controller.commands.sim.field.OnTarget.measured`); ``measured_elsewhere_examples`` the
first ten, each with the heliostat whose beam hit nearest the centroid. ``centroid_error_m``:
how far the measurements' centroids lay from their own beam's true hit — ``measurements``,
``p50``, ``p99``, ``p999``, ``max`` (m; :meth:`controller.commands.sim.field.OnTarget.centroid_errors`).
``controller_ms_per_measurement``, ``plant_ms_per_measurement``: the night's CPU (this process)
per measurement without, and of, the simulated plant's share: its devices' work with the plant
clock stopped (``PlantClock.frozen_cpu_s``: cameras, drive physics), its clock's machinery in
the controller's threads (``PlantClock.clock_cpu_s``, reported as ``night_plant_clock_cpu_s``:
sleeps woken to wait again as the simulated clock's rate changes; a plant's controller sleeps
once per pause) and the benchmark's own truth watcher checking each measurement's centroid in
the cycles' threads (:meth:`controller.commands.sim.field.OnTarget.measured`,
``night_truth_watcher_cpu_s``). ``controller_cpu_s``: CPU seconds of this process and its worker
processes over steps 2-5 — the night's share includes the in-process simulated plant (its cameras
and physics).
``night_user_cpu_s``, ``night_system_cpu_s``: the night's CPU split into user and kernel time, with
its ``night_context_switches`` (voluntary: a thread blocked — mostly on the GIL, handed to
another thread at each release by numpy, OpenCV or SQLite — or waited; involuntary: preempted).
``night_gc``: the garbage collector during the night — how many collections ran at which
``thresholds`` (``"young/middle/old"``), ``collections`` and their ``cpu_s`` per generation
(young, middle, full).

**The peer** (``model``): a discrete-event model of the runner's rules over the same sample
plan — slews at the configured axis speeds, settle and :data:`PROCESS_S` per measurement,
:data:`LAMP_SWITCH_S` per lamp, no runner, camera or drive; ``runner_over_model`` is the ratio
of their plant hours.

    python benchmarks/bench_field.py --heliostats 10000 --targets 3 --json
        [--geometries 3] [--sample 1500] [--night-h 12] [--speedup 200] [--workers 2]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from controller.calibration.campaign.queue_order import slew_time_s
from controller.calibration.cycle.model_update import fit_measurements
from controller.calibration.night.passes import night_passes
from controller.calibration.night.planner import plan_field
from controller.calibration.night.refit import refit_models
from controller.commands.sim.field import (
    OnTarget,
    night_zero,
    run_planned_night,
    seed_from_truth,
    spread,
    strays,
)
from controller.geometry.kinematics import HeliostatKinematics
from controller.reports.night import write_night_report
from controller.storage.db import CampaignStore
from controller.storage.field_records import measurements_by_heliostat, record_models
from controller.storage.nights import NightBook
from simplant.cheap_night import LAMPS, CheapField, field_data

ROOT = Path(__file__).resolve().parents[1]
PROCESS_S = 4.0  # demo: capture, merge, analysis, fit and record per measurement (plant s)
LAMP_SWITCH_S = 60.0  # lights off/on, warm-up


def say(text: str) -> None:
    print(f"bench_field: {text}", file=sys.stderr)


def usage() -> np.ndarray:
    """User CPU s, system CPU s, voluntary and involuntary context switches of this process and
    its (finished) worker processes."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return np.array([[u.ru_utime, u.ru_stime, u.ru_nvcsw, u.ru_nivcsw] for u in (me, kids)]).sum(axis=0)


def cpu_s() -> float:
    """CPU seconds of this process and its (finished) worker processes."""
    return float(usage()[:2].sum())


class GcMeter:
    """The garbage collector's collections per generation and their CPU s (thread time of the
    thread that collected) while entered, and how many ran at which thresholds."""

    def __init__(self) -> None:
        self.collections, self.cpu_s = [0, 0, 0], [0.0, 0.0, 0.0]
        self.at: dict[str, int] = {}
        self._start: dict[int, float] = {}

    def _callback(self, phase: str, info: dict) -> None:
        me = threading.get_ident()
        if phase == "start":
            self._start[me] = time.thread_time()
            key = "/".join(map(str, gc.get_threshold()))
            self.at[key] = self.at.get(key, 0) + 1
        elif me in self._start:
            g = info["generation"]
            self.collections[g] += 1
            self.cpu_s[g] += time.thread_time() - self._start.pop(me)

    def __enter__(self) -> GcMeter:
        gc.callbacks.append(self._callback)
        return self

    def __exit__(self, *exc) -> None:
        gc.callbacks.remove(self._callback)

    def to_json(self) -> dict:
        return {"thresholds": self.at, "collections": self.collections, "cpu_s": self.cpu_s}


def sample_plan(plan, ids: list[str], limit: int, targets: int) -> tuple[list, list[str]]:
    """The plan of every k-th heliostat of ``ids``, k the least that keeps it within ``limit``
    geometries and shares no factor with ``targets`` (heliostat i's target is i mod targets:
    so the sample has every target); all of it when it fits or ``limit`` is 0."""
    if not limit or len(plan) <= limit:
        return plan, ids
    k = int(np.ceil(len(plan) / limit))
    while np.gcd(k, targets) != 1:
        k += 1
    chosen = set(ids[::k])
    return [it for it in plan if it.heliostat_id in chosen], [h for h in ids if h in chosen]


def model_night(data: dict, plan: list, night_s: float) -> dict:
    """The peer: a discrete-event model of the runner's rules (module docstring), lamp by lamp,
    every target its passes; no runner, no camera, no drives."""
    ax = data["heliostats"][0]["axes"]
    az, el = ax["azimuth"], ax["elevation"]
    settle = float(data["calibration"].get("settle_s", 0.5))
    steps = {(it.heliostat_id, it.geometry.lamp, it.geometry.aim_enu): it.geometry.steps for it in plan}
    passes = night_passes(plan, "n1")
    clock, done = 0.0, 0
    for lamp in dict.fromkeys(p.lamp for p in passes):
        if clock + LAMP_SWITCH_S > night_s:
            break
        clock += LAMP_SWITCH_S
        busy = dict.fromkeys((p.target for p in passes if p.lamp == lamp), clock)
        for p in (p for p in passes if p.lamp == lamp):
            for hid, aim in p.aims.items():
                s = steps[(hid, p.lamp, aim)]
                # Standby → aim is a short slew; the slew from stow to standby overlaps the
                # previous heliostat's measurement (pipelining), so only the approach counts.
                approach = max(slew_time_s(0.02 * abs(s[0]), az["speed_steps_per_s"],
                                           az["acceleration_steps_per_s2"]),
                               slew_time_s(0.02 * abs(s[1]), el["speed_steps_per_s"],
                                           el["acceleration_steps_per_s2"]))
                occupancy = 2 * approach + settle + PROCESS_S  # in, measure, back to standby
                if busy[p.target] + occupancy > night_s:
                    break
                busy[p.target] += occupancy
                done += 1
        clock = max(busy.values())
    return {"planned": len(plan), "measured": done, "plant_hours": clock / 3600.0}


def refit_field(cfg, db: Path, workers: int | None) -> dict:
    """Step 4: every model refitted (timed), 20 of them checked against one at a time, stored."""
    store = CampaignStore(db)
    try:
        history = measurements_by_heliostat(store)
        r = refit_models(cfg, history, workers=workers)
        ids = sorted(history)
        check = ids[:: max(1, len(ids) // 20)][:20]
        same = all(_same(r.models[hid], fit_measurements(HeliostatKinematics.from_config(cfg.heliostat(hid)),
                                                         history[hid], cfg.calibration.model))
                   for hid in check)
        record_models(store, {hid: (history[hid][-1], m) for hid, m in r.models.items() if m is not None})
    finally:
        store.close()
    return {"fit_s": r.seconds, "fit_heliostats": len(history),
            "fit_measurements": sum(len(v) for v in history.values()), "fit_same_as_serial": same}


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is b
    return a.params == b.params and a.detail.get("covariance_si") == b.detail.get("covariance_si")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heliostats", type=int, default=1000)
    ap.add_argument("--targets", type=int, default=3)
    ap.add_argument("--geometries", type=int, default=3, help="planned per heliostat and night")
    ap.add_argument("--beams-per-target", type=int, default=1,
                    help="calibration.beams_per_target: beams measured together on a target under lamps")
    ap.add_argument("--sample", type=int, default=1500,
                    help="most geometries the night runs (an evenly spread sample of heliostats beyond); "
                         "0: the whole plan")
    ap.add_argument("--night0-sample", type=int, default=60,
                    help="heliostats calibrated closed loop in night 0 (evenly spread; the rest seeded "
                         "from the plant's truth); 0: all")
    ap.add_argument("--night-h", type=float, default=8.0,
                    help="the night's budget, plant hours (default 8: a summer night)")
    ap.add_argument("--speedup", type=float, default=200.0,
                    help="plant seconds per wall second (<= 1000; higher counts more of the simulator's own "
                         "wall time as plant time)")
    ap.add_argument("--workers", type=int, default=None, help="processes for planning and fitting "
                    "(default: one per core)")
    ap.add_argument("--out", default=None,
                    help="keep the database and report here (default: a temporary folder)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    if not 1 <= args.heliostats <= 50_000 or not 1 <= args.targets <= 3 or not 1 <= args.geometries <= 12:
        ap.exit(2, "bench_field.py: --heliostats in [1, 50000], --targets in [1, 3], "
                   "--geometries in [1, 12]\n")
    if min(args.sample, args.night0_sample) < 0 or not 0 < args.night_h <= 24 or not 0 < args.speedup <= 1000:
        ap.exit(2, "bench_field.py: --sample >= 0, --night0-sample >= 0, --night-h in (0, 24], "
                   "--speedup in (0, 1000]\n")
    if not 1 <= args.beams_per_target <= 8 or (args.workers is not None and not 1 <= args.workers <= 64):
        ap.exit(2, "bench_field.py: --beams-per-target in [1, 8], --workers in [1, 64]\n")
    wall0, load0 = time.perf_counter(), os.getloadavg()
    tmp = None if args.out else tempfile.TemporaryDirectory(prefix="bench-field-")
    out = Path(args.out or tmp.name)
    base = yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())
    data = field_data(base, args.heliostats, args.targets, args.geometries, beams=args.beams_per_target)
    t = time.perf_counter()
    cheap = CheapField(data, out / "field", speedup=args.speedup)
    build_s = time.perf_counter() - t
    cfg, ids = cheap.cfg, [h.id for h in cheap.cfg.heliostats]
    clock = cheap.plant.clock

    # Night 0: closed loop on a sample (the product's calibration campaign), the rest seeded.
    k = args.beams_per_target
    closed = spread(ids, args.night0_sample or len(ids))
    watch = OnTarget(cheap, None)
    z = night_zero(cheap, closed, "field/night-0", 3600.0 * 24, observers=[watch])
    z_bad, z_caps, _ = strays(cheap, k, {})
    say(f"night 0 closed loop: {z.calibrated}/{z.heliostats} calibrated, {z.measurements} measurements, "
        f"{z.plant_s / 3600:.2f} plant h, {z.wall_s:.0f} s wall")
    rest = [h for h in ids if h not in set(closed)]
    t = time.perf_counter()
    seed = seed_from_truth(cheap, "field/night-0-seeded", workers=args.workers, heliostat_ids=rest) if rest \
        else {"unreachable": []}
    seed_s = time.perf_counter() - t
    night0_h = z.plant_s / 3600.0 * len(ids) / max(1, z.heliostats)

    store = CampaignStore(cheap.db_path, readonly=True)
    try:
        book = NightBook(store)
        night, index = f"{book.base_name()}/night-{book.next_index()}", book.next_index()
        models = store.latest_models(ids)
    finally:
        store.close()
    plan = plan_field(cfg, {hid: models.get(hid) for hid in ids}, night, night_index=index,
                      workers=args.workers)
    say(f"planned {len(plan.items)} geometries for {plan.decisions} heliostats in {plan.seconds:.1f} s; "
        f"{len(plan.unmeasurable)} with no measurable geometry")
    items, sampled = sample_plan(plan.items, ids, args.sample, args.targets)
    watch = OnTarget(cheap, items)
    since = {tid: len(cam.beams_in_view) for tid, cam in cheap.cameras.items()}
    cpu0, sim0, tick0, use0 = cpu_s(), clock.frozen_cpu_s, clock.clock_cpu_s, usage()
    watch0 = watch.cpu_s
    with GcMeter() as collector:
        r = run_planned_night(cheap, items, night, 3600.0 * args.night_h, heliostat_ids=ids,
                              unmeasurable=plan.unmeasurable, workers=args.workers, observers=[watch])
    # The simulated plant's CPU: its devices' (frozen blocks), its clock's machinery and the
    # benchmark's truth watcher.
    tick_cpu, watch_cpu = clock.clock_cpu_s - tick0, watch.cpu_s - watch0
    night_cpu, night_use = cpu_s() - cpu0, usage() - use0
    plant_cpu = clock.frozen_cpu_s - sim0 + tick_cpu + watch_cpu
    say(f"night: {len(r.measured)}/{r.planned} measured, {r.plant_s / 3600:.2f} plant h, "
        f"{r.wall_s:.0f} s wall, {night_cpu:.0f} s CPU ({plant_cpu:.0f} s of it the simulated plant's)")
    fit = refit_field(cfg, cheap.db_path, args.workers)
    say(f"refit {fit['fit_heliostats']} models in {fit['fit_s']:.1f} s")
    t = time.perf_counter()
    store = CampaignStore(cheap.db_path, readonly=True)
    try:
        rec = next(n for n in NightBook(store).nights() if n.name == night)
        write_night_report(store, out / "report", rec)
    finally:
        store.close()
    report_s = time.perf_counter() - t
    cpu = cpu_s() - cpu0

    failed: dict[str, int] = {}
    for run in (run for res in r.results for run in res.runs if run.status != "measured"):
        kind = (run.fault_cause or run.status).split(":")[0]
        failed[kind] = failed.get(kind, 0) + 1
    peer = model_night(data, items, 3600.0 * args.night_h)
    bad, captures, examples = strays(cheap, k, since)
    measured = len(r.measured)
    # The whole plan's plant hours at the night's rate (a sample's, or a night the budget ended).
    whole_h = (r.plant_s / 3600.0 * len(plan.items) / max(1, measured if r.stopped_by_budget else r.planned))
    result = {
        "benchmark": "field night (the product's PlannedNight, cheap optics)",
        "heliostats": len(ids), "targets": args.targets, "geometries_per_heliostat": args.geometries,
        "beams_per_target": k, "lamps": len(LAMPS), "planned": r.planned, "measured": measured,
        "measured_fraction": measured / r.planned if r.planned else None,
        "plan_total": len(plan.items), "unmeasurable": len(plan.unmeasurable),
        "sample": {"heliostats": len(sampled), "of": len(ids), "limit_geometries": args.sample},
        "second_beam_captures": bad, "captures": captures, "second_beam_examples": examples,
        "second_beam_heliostats": watch.strays_by_heliostat(),
        "measured_elsewhere": len(watch.elsewhere), "measured_elsewhere_examples": watch.elsewhere[:10],
        "centroid_error_m": watch.centroid_errors(),
        "runs_not_measured": failed, "night_status": r.summary.status, "night_cause": r.summary.cause,
        "plant_hours": r.plant_s / 3600.0, "plant_hours_whole_plan": whole_h,
        "nights_needed": math.ceil(whole_h / args.night_h - 1e-9),
        "ended_by_night_budget": r.stopped_by_budget,
        "controller_ms_per_measurement": 1e3 * (night_cpu - plant_cpu) / max(1, measured),
        "plant_ms_per_measurement": 1e3 * plant_cpu / max(1, measured),
        "night_cpu_s": night_cpu, "night_plant_cpu_s": plant_cpu, "night_plant_clock_cpu_s": tick_cpu,
        "night_truth_watcher_cpu_s": watch_cpu,
        "night_wall_s": r.wall_s,
        "night_gc": collector.to_json(),
        "night_user_cpu_s": night_use[0], "night_system_cpu_s": night_use[1],
        "night_context_switches": {"voluntary": int(night_use[2]), "involuntary": int(night_use[3])},
        "night0": {"closed_loop_heliostats": z.heliostats, "calibrated": z.calibrated, "statuses": z.statuses,
                   "measurements": z.measurements, "plant_hours": z.plant_s / 3600.0, "wall_s": z.wall_s,
                   "captures_with_a_stray_beam": z_bad, "captures": z_caps,
                   "seeded_from_truth": len(rest), "seed_unreachable": len(seed["unreachable"]),
                   "seed_s": seed_s},
        "night0_plant_hours": night0_h,
        "nights_to_first_planned_night": math.ceil(night0_h / args.night_h - 1e-9),
        "planner_ms_per_decision": 1e3 * plan.seconds / max(1, plan.decisions), "decisions": plan.decisions,
        "planner_ms_per_geometry": 1e3 * plan.seconds / max(1, len(plan.items)),
        "plan_s": plan.seconds, **fit, "report_s": report_s, "build_s": build_s,
        "controller_cpu_s": cpu, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "workers_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0,
        "daytime_error_predicted_mrad": r.summary.daytime_error_predicted_mrad,
        "model": peer, "runner_over_model": (r.plant_s / 3600.0) / max(peer["plant_hours"], 1e-9),
        "workers": args.workers, "clock_speedup": args.speedup, "night_budget_h": args.night_h,
        "load_average": {"start": load0, "end": os.getloadavg()}, "cores": os.cpu_count(),
        "wall_s": time.perf_counter() - wall0,
    }
    if tmp is not None:
        tmp.cleanup()
    print(json.dumps(result, indent=None if args.json else 1))


if __name__ == "__main__":
    main()
