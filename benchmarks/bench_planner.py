"""The nightly planner against a fixed round-robin schedule, on the independent simulated truth.

For each heliostat of the demo field a hidden heliostat is drawn (:mod:`simplant.truth`:
actuator geometry, pedestal, joints, droop, stroke scale, position error, nightly drift — not
the controller's model). Night 0 measures each heliostat once at the calibration lamp and
target centre (its nominal pose: the closed-loop campaign's first capture), which gives the
first model. Each night, each schedule plans the same number of measurements
(``geometries_per_night`` per heliostat, from the same candidate geometries); a measurement
is the truth's beam spot on the target plane for the planned steps (central ray from the
true mirror centre, plus 0.2 mrad of noise), the fit uses every measurement so far, and the
*true* open-loop daytime error is scored over the yearly sun path (the demo's figure,
without the camera). Prints JSON: per night and schedule the field's true daytime RMS/p95
and the predicted RMS; the ratio round-robin / planner after the last night.

``--layout`` scores a plant layout (lamps, aim grid) without any truth: each heliostat's prior
covariance is updated (Eq. 1 of :mod:`controller.geometry.design`) by one observation at the
calibration lamp and target centre (the closed-loop calibration) and then by the planner's
picks night after night, and the field's *predicted* daytime RMS (Eq. 2) is printed — the
figure the demo's lamp layout was chosen on (docs/campaigns.md, "Lamp layout"). Nightly drift
is left out, so it is a floor of what the fit reports.

    python benchmarks/bench_planner.py [--nights 3] [--heliostats 12] [--seed 0]
    python benchmarks/bench_planner.py --layout [--config configs/demo.yaml]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml

from controller.calibration.cycle.model_update import fit_measurements
from controller.calibration.night.daytime import model_covariance, predicted_daytime, sun_path, tracking_steps
from controller.calibration.night.planner import Geometry, PlanItem, candidates, plan_night, planner_sun
from controller.calibration.records import MeasurementRecord
from controller.config import parse_config
from controller.geometry.aiming import angle_mrad, intersect_plane, reflected_beam, source_direction
from controller.geometry.design import (
    beam_jacobians,
    daytime_variance,
    greedy_design,
    normal_jacobian,
    posterior,
)
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import model_aim
from simplant.plant import field_selection
from simplant.truth import hidden_truth

ROOT = Path(__file__).resolve().parents[1]
NOISE_RAD = 0.2e-3


def measure(truth, cfg, item, night: int, rng) -> MeasurementRecord:
    """The planned geometry measured on the truth: its spot on the target plane (m ENU)."""
    g = item.geometry
    lamp = np.asarray(cfg.light_source(g.lamp).position_enu_m, float)
    n = truth.normal(*g.steps, night=night)
    tilt = rng.normal(0.0, NOISE_RAD / 2.0, 3)  # half of the beam noise is the normal's
    n = n + tilt - (tilt @ n) * n
    n /= np.linalg.norm(n)
    c = truth.mirror_center(*g.steps, night=night)
    s = (lamp - c) / np.linalg.norm(lamp - c)
    t = cfg.target()
    spot = intersect_plane(c, reflected_beam(s, n), np.asarray(t.center_enu_m, float),
                           np.asarray(t.normal, float))
    nominal = np.asarray(cfg.heliostat(item.heliostat_id).position_enu_m, float)
    src = (lamp - nominal) / np.linalg.norm(lamp - nominal)
    stamp = f"2026-03-{1 + night:02d}T21:00:00+00:00"
    return MeasurementRecord(iteration=1, az_steps=g.steps[0], el_steps=g.steps[1], source_dir=tuple(src),
                             source_az_deg=0.0, source_el_deg=0.0, aim_enu=g.aim_enu, plant_time_s=0.0,
                             measured_utc=stamp, centroid_enu=tuple(float(v) for v in spot),
                             source_pos_enu=tuple(float(v) for v in lamp))


def true_daytime(cfg, truths, models, path, night: int) -> tuple[float, float]:
    """Field RMS and p95 of the true reflected-beam error over the sun path, mrad."""
    target = np.asarray(cfg.target().center_enu_m, float)
    errs = []
    for hid, truth in truths.items():
        steps, ok = tracking_steps(cfg.heliostat(hid), models.get(hid), path.directions, target)
        for (az, el), s in zip(steps[ok], path.directions[ok], strict=True):
            n = truth.normal(az, el, night=night)
            c = truth.mirror_center(az, el, night=night)
            errs.append(angle_mrad(2.0 * float(s @ n) * n - s, target - c))
    e = np.asarray(errs)
    return float(np.sqrt(np.mean(e**2))), float(np.percentile(e, 95))


def calibration_item(cfg, hid: str) -> PlanItem:
    """The calibration night's geometry of ``hid``: the calibration lamp onto the target centre
    with the nominal kinematics (the closed-loop campaign's first pose)."""
    lamp = cfg.light_source()
    centre = np.asarray(cfg.target().center_enu_m, float)
    h = cfg.heliostat(hid)
    pos = np.asarray(h.position_enu_m, float)
    steps = HeliostatKinematics.from_config(h).aim(source_direction(lamp, pos), centre,
                                                   lamp_position=np.asarray(lamp.position_enu_m, float))
    return PlanItem(hid, "night-0", Geometry(lamp.id, tuple(float(v) for v in centre), (0, 0), steps), 1, 0.0,
                    0.0, 0.0)


def run(strategy: str, cfg, truths, nights: int, seed: int, path) -> list[dict]:
    rng = np.random.default_rng([seed, 99])
    # Night 0: each heliostat measured once at the calibration geometry (the planner plans only
    # geometries whose spot it can predict inside the camera's view: it needs a first model).
    history: dict[str, list[MeasurementRecord]] = {
        hid: [measure(truths[hid], cfg, calibration_item(cfg, hid), 0, rng)] for hid in truths}
    models: dict = {hid: fit_measurements(HeliostatKinematics.from_config(cfg.heliostat(hid)), ms,
                                          cfg.calibration.model) for hid, ms in history.items()}
    out = []
    for k in range(nights):
        t0 = time.perf_counter()
        plan = plan_night(cfg, models, f"night-{k + 1}", strategy=strategy, night_index=k)
        planner_s = time.perf_counter() - t0
        for item in plan:
            history[item.heliostat_id].append(measure(truths[item.heliostat_id], cfg, item, k, rng))
        for hid, ms in history.items():
            kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
            models[hid] = fit_measurements(kin, ms, cfg.calibration.model) or models[hid]
        rms, p95 = true_daytime(cfg, truths, models, path, k)
        pred = predicted_daytime(cfg, models, path)
        out.append({"night": k + 1, "measurements": len(plan), "true_rms_mrad": rms, "true_p95_mrad": p95,
                    "predicted_rms_mrad": pred.rms, "planner_s_per_heliostat": planner_s / len(truths)})
    return out


def layout_rms(cfg, hid: str, index: int, nights: int) -> tuple[float, int]:
    """Predicted daytime RMS (mrad, sqrt of Eq. 2) of one heliostat after the calibration
    observation and ``nights`` planned nights (module docstring, ``--layout``), and the number
    of planned measurements. Uses the model only: no truth, no measurement."""
    cal = cfg.calibration
    model, cov = model_covariance(None, cal.model)
    kin = HeliostatKinematics.from_config(cfg.heliostat(hid))
    centre = np.asarray(cfg.target().center_enu_m, float)
    a = beam_jacobians(kin, model, planner_sun(cfg), centre)
    noise = cal.model.noise_mrad * 1e-3
    lamp = cfg.light_source(cal.light_source)
    s = np.asarray(source_direction(lamp, np.asarray(cfg.heliostat(hid).position_enu_m, float)), float)
    cov = posterior(cov, normal_jacobian(kin, model, *model_aim(kin, model, s, centre), None, centre,
                                         np.asarray(lamp.position_enu_m, float)), noise)
    targets = cal.parallel_targets()
    planned = 0
    for k in range(nights):  # the target share of plan_night: heliostat i takes (i + k) mod n
        geos = candidates(cfg, hid, model, (targets[(index + k) % len(targets)],))
        hs = [normal_jacobian(kin, model, *g.steps, None, np.asarray(g.aim_enu),
                              np.asarray(cfg.light_source(g.lamp).position_enu_m, float)) for g in geos]
        within = 1e3 * np.sqrt(daytime_variance(a, cov)) <= cal.tolerance_mrad
        n = cal.planner.check_geometries if within else cal.planner.geometries_per_night
        picks, cov = greedy_design(cov, hs, a, noise, n)
        planned += len(picks)
    return 1e3 * float(np.sqrt(daytime_variance(a, cov))), planned


def layout(cfg, n: int, nights: int) -> dict:
    """The ``--layout`` figure for the ``n`` heliostats the demo takes (round-robin over links)."""
    per = {hid: layout_rms(cfg, hid, i, nights) for i, hid in enumerate(field_selection(cfg, n))}
    rms = [v[0] for v in per.values()]
    return {"benchmark": "planner-layout", "heliostats": len(per), "nights": nights,
            "predicted_rms_mrad": float(np.sqrt(np.mean(np.square(rms)))),
            "predicted_max_mrad": max(rms), "planned": sum(v[1] for v in per.values()),
            "per_heliostat_mrad": {hid: round(v[0], 3) for hid, v in per.items()},
            "peer": "none: the model's own prediction, for comparing layouts"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nights", type=int, default=3)
    ap.add_argument("--heliostats", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--layout", action="store_true", help="predicted daytime RMS only (no truth)")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "demo.yaml")
    args = ap.parse_args()
    cfg = parse_config(yaml.safe_load(args.config.read_text()), str(args.config))
    if args.layout:
        print(json.dumps(layout(cfg, args.heliostats, args.nights), indent=1))
        return
    ids = [h.id for h in cfg.heliostats][: args.heliostats]
    truths = {hid: hidden_truth(cfg.heliostat(hid), np.random.default_rng([args.seed, 7, i]), 1.0)
              for i, hid in enumerate(ids)}
    path = sun_path(cfg.site)
    uncal = true_daytime(cfg, truths, {}, path, 0)
    design = run("design", cfg, truths, args.nights, args.seed, path)
    fixed = run("round-robin", cfg, truths, args.nights, args.seed, path)
    print(json.dumps({
        "benchmark": "planner", "heliostats": len(ids), "nights": args.nights, "seed": args.seed,
        "uncalibrated_rms_mrad": uncal[0], "design": design, "round_robin": fixed,
        "ratio_round_robin_over_design_rms": fixed[-1]["true_rms_mrad"] / design[-1]["true_rms_mrad"],
        "peer": "round-robin over the same candidates, same number of measurements",
    }, indent=1))


if __name__ == "__main__":
    main()
