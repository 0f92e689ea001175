"""One planned night of a 1,000-heliostat field with several targets and six lamps.

The field: heliostats on staggered rows north of the tower (40-300 m), each with the demo's
AA39 actuators; up to three targets on the tower (upper, middle, lower; each with its camera
and a 2 × 2 aim grid, all in ``calibration.targets``); six lamps. The queue is shared out
over the targets by the planner's own rule (heliostat i takes target i mod n on the first
night, :func:`controller.calibration.planner.plan_night`), and per heliostat the real planner
(:func:`controller.calibration.planner.plan_heliostat`) chooses tonight's geometries on its
target — timed per decision.

The night is **not a run of the runner**: it is a discrete-event model of its rules in plant
time, with cheap optics (no ray tracing, no camera, no drives). The passes are the runner's
own (:func:`controller.calibration.nights.night_passes`: per lamp, per target, per rank);
under one lamp every target works through its passes at the same time, one beam per target
(the runner's one thread, gate and camera per target), and the next lamp is lit when every
target is done (:data:`LAMP_SWITCH_S`). Per measurement the target is occupied for the
approach from standby and back, at the configured axis speeds
(:func:`controller.calibration.planning.slew_time_s`; the slew to standby overlaps the
previous measurement: pipelining), the settle time and the capture-to-record time measured
in the demo (:data:`PROCESS_S`). The night's budget is 8 h. It prints JSON: planner time
per decision, plant time used, wall time, measurements and heliostats covered,
heliostats/hour/target — for one, two and three targets, to show how the night's coverage
scales with the number of targets.

    python benchmarks/bench_field.py [--heliostats 1000] [--planned 200] [--geometries 3]

``--planned`` heliostats are planned by the real planner (its time per decision is
measured on them); the others reuse the plan of the planned heliostat nearest to them on the
same target, which keeps the benchmark within minutes.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from controller.calibration.nights import night_passes
from controller.calibration.planner import plan_heliostat, planner_sun
from controller.calibration.planning import slew_time_s
from controller.config import parse_config

ROOT = Path(__file__).resolve().parents[1]
NIGHT_S = 8 * 3600.0
PROCESS_S = 4.0  # demo: capture, merge, analysis, fit and record per measurement (plant s)
LAMP_SWITCH_S = 60.0  # lights off/on, warm-up
TARGET_HEIGHTS = (40.0, 30.0, 20.0)
LAMPS = ([0.0, 5.0, 60.0], [-60.0, 30.0, 25.0], [60.0, 30.0, 25.0], [0.0, 3.0, 8.0],
         [-200.0, 40.0, 40.0], [200.0, 40.0, 40.0])


def field_config(n: int, targets: int, geometries: int = 3) -> dict:
    base = yaml.safe_load((ROOT / "configs" / "demo.yaml").read_text())
    proto = base["heliostats"][0]
    data = copy.deepcopy(base)
    data["targets"] = [{"id": f"T{k + 1}", "center_enu_m": [0.0, 0.0, h], "normal": [0.0, 1.0, 0.0],
                        "width_m": 8.0, "height_m": 7.0} for k, h in enumerate(TARGET_HEIGHTS[:targets])]
    data["light_sources"] = [{"kind": "sun", "id": "sun", "angular_diameter_mrad": 9.3}] + [
        {"kind": "lamp", "id": f"L{i + 1}", "position_enu_m": p, "diameter_m": 0.3}
        for i, p in enumerate(LAMPS)]
    cal = data["calibration"]
    cal.update(light_source="L1", target="T1", targets=[f"T{k + 1}" for k in range(targets)],
               lamps=[f"L{i + 1}" for i in range(len(LAMPS))],
               aim_grid={"rows": 2, "cols": 2, "margin_m": 2.5},
               planner={"geometries_per_night": geometries, "check_geometries": 1, "sun_positions": 16})
    hs, r, k = [], 40.0, 0
    while len(hs) < n:
        count = int(2 * math.pi * r / 2 / 6.0)  # half a circle, 6 m apart
        for j in range(count):
            if len(hs) == n:
                break
            az = math.radians(-70.0 + 140.0 * (j + 0.5 * (k % 2)) / count)
            h = copy.deepcopy(proto)
            h["id"] = f"F{len(hs) + 1:04d}"
            h["position_enu_m"] = [round(r * math.sin(az), 2), round(r * math.cos(az), 2), 2.0]
            # 30 heliostats per serial bus (never opened here: the night is simulated).
            h["link"] = {**proto["link"], "address": 1 + len(hs) % 30,
                         "device": f"/dev/heliocal-bus{len(hs) // 30}"}
            hs.append(h)
        r += 7.0
        k += 1
    data["heliostats"] = hs
    return data


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


def run_night(data: dict, plans: dict[str, list], targets: int) -> dict:
    """Discrete-event night (module docstring): lamp by lamp, every target its passes."""
    ax = data["heliostats"][0]["axes"]
    az, el = ax["azimuth"], ax["elevation"]
    settle = float(data["calibration"].get("settle_s", 0.5))
    steps = {(it.heliostat_id, it.geometry.lamp, it.geometry.aim_enu): it.geometry.steps
             for p in plans.values() for it in p}
    passes = night_passes([it for p in plans.values() for it in p], "n1")
    clock, done, helios = 0.0, 0, set()
    per_target = {}
    for lamp in dict.fromkeys(p.lamp for p in passes):
        if clock + LAMP_SWITCH_S > NIGHT_S:
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
                if busy[p.target] + occupancy > NIGHT_S:
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heliostats", type=int, default=1000)
    ap.add_argument("--planned", type=int, default=200)
    ap.add_argument("--geometries", type=int, default=3,
                    help="planned per heliostat (more than one target's night holds shows the coverage "
                         "gained by more targets)")
    args = ap.parse_args()
    wall0 = time.perf_counter()
    rows = []
    planner = {}
    for targets in (1, 2, 3):
        data = field_config(args.heliostats, targets, args.geometries)
        plans, per, n = plan_field(data, targets, args.planned)
        planner[targets] = {"s_per_decision": per, "decisions_timed": n}
        rows.append(run_night(data, plans, targets))
    print(json.dumps({"benchmark": "field night", "heliostats": args.heliostats, "lamps": len(LAMPS),
                      "night_budget_h": NIGHT_S / 3600.0, "planner": planner, "by_targets": rows,
                      "geometries_per_heliostat": args.geometries,
                      "coverage_ratio_3_over_1_target":
                          rows[-1]["measurements"] / max(1, rows[0]["measurements"]),
                      "plant_time_ratio_1_over_3_targets": rows[0]["plant_time_h"] / rows[-1]["plant_time_h"],
                      "wall_s": time.perf_counter() - wall0}, indent=1))


if __name__ == "__main__":
    main()
