"""One planned night of a 1,000-heliostat field with 1, 2 and 3 targets, run by the real runner.

The field (:func:`simplant.cheap_night.field_data`): heliostats on staggered half rings north
of the tower (40-300 m), each with the demo's AA39 actuators; up to three targets on the tower
(upper, middle, lower, each with its camera, a 2 × 2 aim grid, all in
``calibration.targets``); six lamps. The queue is shared out over the targets by the
planner's rule (heliostat i takes target i mod n on the first night,
:func:`controller.calibration.planner.plan_night`); per heliostat the real planner
(:func:`controller.calibration.planner.plan_heliostat`) chooses the night's geometries on its
target, timed per decision. ``--planned`` heliostats are planned (default 200 of the 1,000:
planning all takes ~0.1 s each on this machine); the others take the aim points of the
planned heliostat nearest to them on the same target.

**The run** (:func:`controller.commands._cheap_night.run_cheap_night` on a
:class:`simplant.cheap_night.CheapField`): the product's night
(:class:`controller.calibration.night.PlannedNight`, as ``heliocal campaign night`` runs it:
lamp changes in the dark, one :class:`controller.calibration.runner.Campaign` per pass, the
targets of a lamp in parallel, state machine, gate per target, fit, SQLite store) against the
simulated plant's hidden
heliostats, driven in-process through the firmware physics (:mod:`simplant.inproc`) and seen
by cheap analytic-spot cameras (:mod:`simplant.cheap_camera`, 128 × 96), on the plant clock at
``--speedup`` (the controller's own computing runs at 1x plant time). The night ends after
``--night-h`` plant hours (every running campaign is stopped as by Ctrl-C) or when every pass
is done.

**The peer** (``model``): the discrete-event model of the runner's rules this benchmark used
to be — same plans, same passes (:func:`controller.calibration.nights.night_passes`), slews at
the configured axis speeds (:func:`controller.calibration.planning.slew_time_s`), settle and
:data:`PROCESS_S` per measurement, :data:`LAMP_SWITCH_S` per lamp; no runner, camera or drive.
``runner_over_model`` is the ratio of their heliostats/hour/target.

    python benchmarks/bench_field.py [--heliostats 1000] [--planned 200] [--geometries 3]
                                     [--night-h 8] [--speedup 100]

It prints JSON: per target count, the runner's plant time, wall time, measurements done /
planned, heliostats covered, heliostats/hour/target, the planner's time per decision,
captures with more than one beam in a target's view (the plant's truth), and the model peer.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from controller.calibration.nights import night_passes
from controller.calibration.planner import plan_heliostat, planner_sun
from controller.calibration.planning import slew_time_s
from controller.commands._cheap_night import run_cheap_night
from controller.config import parse_config
from simplant.cheap_night import LAMPS, CheapField, field_data

ROOT = Path(__file__).resolve().parents[1]
PROCESS_S = 4.0  # demo: capture, merge, analysis, fit and record per measurement (plant s)
LAMP_SWITCH_S = 60.0  # lights off/on, warm-up


def target_of(index: int, targets: int) -> int:
    """The target of the heliostat at ``index`` on the first night: the planner's rule
    (:func:`controller.calibration.planner.plan_night`, i mod n)."""
    return index % targets


def plan_field(data: dict, targets: int, planned: int) -> tuple[dict[str, list], float, int]:
    """Plans per heliostat (real planner on ``planned`` of them), seconds per decision, decisions."""
    cfg = parse_config(data, f"field-{targets}")
    tids = cfg.calibration.parallel_targets()
    sun = planner_sun(cfg)
    hs = data["heliostats"]
    sample = set(np.linspace(0, len(hs) - 1, min(planned, len(hs))).round().astype(int).tolist())
    plans: dict[str, list] = {}
    t0 = time.perf_counter()
    for i in sorted(sample):
        plans[hs[i]["id"]] = plan_heliostat(cfg, hs[i]["id"], None, "n1", sun,
                                            targets=(tids[target_of(i, targets)],))
    per = (time.perf_counter() - t0) / max(1, len(sample))
    for i, h in enumerate(hs):
        if h["id"] not in plans:
            near = min((j for j in sample if target_of(j, targets) == target_of(i, targets)),
                       key=lambda j: np.hypot(hs[j]["position_enu_m"][0] - h["position_enu_m"][0],
                                              hs[j]["position_enu_m"][1] - h["position_enu_m"][1]))
            plans[h["id"]] = [replace(it, heliostat_id=h["id"]) for it in plans[hs[near]["id"]]]
    return plans, per, len(sample)


def model_night(data: dict, plans: dict[str, list], targets: int, night_s: float) -> dict:
    """The peer: a discrete-event model of the runner's rules (module docstring), lamp by
    lamp, every target its passes; no runner, no camera, no drives."""
    ax = data["heliostats"][0]["axes"]
    az, el = ax["azimuth"], ax["elevation"]
    settle = float(data["calibration"].get("settle_s", 0.5))
    steps = {(it.heliostat_id, it.geometry.lamp, it.geometry.aim_enu): it.geometry.steps
             for p in plans.values() for it in p}
    passes = night_passes([it for p in plans.values() for it in p], "n1")
    clock, done, helios = 0.0, 0, set()
    per_target = {}
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
                per_target[p.target] = per_target.get(p.target, 0.0) + occupancy
                done += 1
                helios.add(hid)
        clock = max(busy.values())
    planned = sum(len(p) for p in plans.values())
    used = clock
    return {"targets": targets, "planned_measurements": planned, "measurements": done,
            "coverage": done / planned if planned else float("nan"), "heliostats_covered": len(helios),
            "plant_time_h": used / 3600.0,
            "target_occupancy_h": {str(t): v / 3600.0 for t, v in per_target.items()},
            "heliostats_per_hour_per_target": len(helios) / (used / 3600.0) / targets if used else 0.0}


def runner_night(data: dict, plans: dict[str, list], targets: int, night_s: float, speedup: float) -> dict:
    """The night through the real runner over the cheap plant (module docstring)."""
    with tempfile.TemporaryDirectory(prefix="bench-field-") as tmp:
        f = CheapField(data, Path(tmp), speedup=speedup)
        r = run_cheap_night(f, [it for p in plans.values() for it in p], "n1", night_s)
    hours = r.plant_s / 3600.0
    several = {t: sum(1 for b in v if len(b) > 1) for t, v in r.beams_in_view.items()}
    failed: dict[str, int] = {}  # runs not measured, by the exception that ended them
    for run in (run for res in r.results for run in res.runs if run.status != "measured"):
        kind = (run.fault_cause or run.status).split(":")[0]
        failed[kind] = failed.get(kind, 0) + 1
    return {"targets": targets, "planned_measurements": r.planned, "measurements": len(r.measured),
            "coverage": len(r.measured) / r.planned if r.planned else float("nan"),
            "heliostats_covered": len(r.heliostats), "plant_time_h": hours, "wall_s": r.wall_s,
            "ended_by_night_budget": r.stopped_by_budget, "measurements_per_target": r.per_target,
            "captures": {t: len(v) for t, v in r.beams_in_view.items()},
            "captures_with_several_beams_in_view": several, "runs_not_measured": failed,
            "passes": {res.status: sum(1 for x in r.results if x.status == res.status) for res in r.results},
            "heliostats_per_hour_per_target": len(r.heliostats) / hours / targets if hours else 0.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heliostats", type=int, default=1000)
    ap.add_argument("--planned", type=int, default=200, help="heliostats planned by the real planner")
    ap.add_argument("--geometries", type=int, default=1,
                    help="planned per heliostat (3 through the runner: ~0.12 s wall per measurement, "
                         "over 10 min for the three target counts)")
    ap.add_argument("--night-h", type=float, default=8.0, help="the night's budget, plant hours")
    ap.add_argument("--speedup", type=float, default=100.0,
                    help="plant seconds per wall second (<= 1000; higher counts more of the simulator's own "
                         "wall time as plant time)")
    args = ap.parse_args()
    for name in ("heliostats", "planned", "geometries"):
        if getattr(args, name) < 1:
            ap.exit(2, f"bench_field.py: --{name} must be at least 1\n")
    if not 0 < args.night_h <= 24 or not 0 < args.speedup <= 1000:
        ap.exit(2, "bench_field.py: --night-h must be in (0, 24] and --speedup in (0, 1000]\n")
    base = yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())
    wall0 = time.perf_counter()
    rows = []
    for targets in (1, 2, 3):
        data = field_data(base, args.heliostats, targets, args.geometries)
        plans, per, n = plan_field(data, targets, args.planned)
        run = runner_night(data, plans, targets, 3600.0 * args.night_h, args.speedup)
        print(f"bench_field: {targets} target(s): {run['measurements']}/{run['planned_measurements']} "
              f"measured, {run['plant_time_h']:.2f} plant h, {run['wall_s']:.0f} s wall", file=sys.stderr)
        model = model_night(data, plans, targets, 3600.0 * args.night_h)
        rows.append({**run, "planner": {"s_per_decision": per, "decisions_timed": n}, "model": model,
                     "runner_over_model": run["heliostats_per_hour_per_target"]
                     / max(model["heliostats_per_hour_per_target"], 1e-12)})
    print(json.dumps({"benchmark": "field night (real runner, cheap optics)", "heliostats": args.heliostats,
                      "lamps": len(LAMPS), "night_budget_h": args.night_h, "clock_speedup": args.speedup,
                      "geometries_per_heliostat": args.geometries, "by_targets": rows,
                      "coverage_ratio_3_over_1_target":
                          rows[-1]["measurements"] / max(1, rows[0]["measurements"]),
                      "wall_s": time.perf_counter() - wall0}, indent=1))


if __name__ == "__main__":
    main()
