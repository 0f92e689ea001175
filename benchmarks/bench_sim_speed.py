"""Benchmark of the simulated plant's per-frame work in ``heliocal demo``, against the previous
implementation as named peers.

The demo's CPU went mostly to the simulator (profile in docs/campaigns.md): every capture
renders the scene and exposes two 1024 x 768 sensors, and the beam-safety monitor looks at
every heliostat 50 times a second. Measured here on the demo plant (``controller/data/demo.yaml``)
with one heliostat's beam on the calibration target:

* ``capture``: one rendered and exposed frame pair of the plant camera (scene, perspective
  warp, both sensors); peer ``poisson_sensor``: the same camera with exact Poisson shot noise in
  float64 (the sensors as they were, still ``SensorModel(shot="poisson")``);
* ``safety_sample``: one sample of the beam-safety monitor over both targets, heliostats at
  rest (their poses kept); ``safety_sample_all_moving``: the same with every pose recomputed
  (all heliostats slewing, the worst case); peer ``per_target_recompute``: the previous monitor
  (below), which recomputed every heliostat's true normal and mirror centre for each target
  with every rotation rebuilt.

Times are CPU time of this thread (``time.thread_time``: other jobs on the machine do not
inflate them; OpenCV limited to one thread), medians over ``--runs``. Prints one JSON object
with both figures of each phase and ``*_speedup`` = peer / ours.

Usage: .venv/bin/python benchmarks/bench_sim_speed.py [--runs 20]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

import controller
from controller.config import load_config
from controller.geometry.nominal_aim import nominal_aims
from controller.geometry.vectors import unit
from simplant.devices.grids import camera_grid
from simplant.devices.plant_camera import PlantCamera
from simplant.plant import SimulatedPlant, field_selection, load_config_data
from simplant.truth import EAST, FACING_SOUTH, NORTH, UP, rodrigues

DEMO = Path(controller.__file__).parent / "data" / "demo.yaml"


def cpu_ms(fn, runs: int) -> float:
    """Median CPU time of ``fn()`` in this thread, ms (after one warm-up call)."""
    fn()
    times = []
    for _ in range(runs):
        t0 = time.thread_time()
        fn()
        times.append(time.thread_time() - t0)
    return statistics.median(times) * 1e3


def previous_normal(t, az: float, el: float, night: int, jitter) -> tuple[np.ndarray, np.ndarray]:
    """The hidden heliostat's normal and mirror centre as computed before: both joint frames
    and the constant rotations rebuilt on every call."""
    def frame(jit):
        d_el, d_az = t._drift(night)
        eps = t.elevation.angle(el) + d_el
        eps += t.droop * math.sin(eps)
        alpha = t.azimuth.angle(az) + d_az
        if jit is not None:
            eps, alpha = eps + float(jit[0]), alpha + float(jit[1])
        joint_up = rodrigues(NORTH, t.non_orthogonality) @ UP
        return t.pedestal @ rodrigues(EAST, eps - math.pi / 2.0) @ rodrigues(joint_up, alpha)

    cant = rodrigues(EAST, t.canting[0]) @ rodrigues(UP, t.canting[1])
    n = frame(jitter) @ cant @ FACING_SOUTH
    return n / np.linalg.norm(n), t.position + frame(None) @ t.concentrator


def previous_sample(plant: SimulatedPlant) -> dict[str, list[str]]:
    """Peer: the previous monitor's sample, target by target, every pose recomputed."""
    out = {}
    for tgt in plant.cfg.targets:
        c, nrm = np.asarray(tgt.center_enu_m, float), unit(np.asarray(tgt.normal, float))
        base = camera_grid(plant.cfg.for_target(tgt.id))
        lamp = np.asarray(plant.lamp().position_enu_m, float)
        on = []
        for hid, hh in plant.hidden.items():
            steps = hh.controller.output_steps()
            n, _ = previous_normal(hh.truth, *steps, plant.night, hh.settle(tuple(steps), plant.night))
            _, pos = previous_normal(hh.truth, *hh.controller.output_steps(), plant.night, None)
            s = unit(lamp - pos)
            beam = 2.0 * (s @ n) * n - s
            den = float(nrm @ beam)
            if abs(den) < 1e-9:
                continue
            t = float(nrm @ (c - pos)) / den
            if t > 0:
                rel = pos + t * beam - c
                if abs(rel @ base.u_axis) <= tgt.width_m / 2 and abs(rel @ base.v_axis) <= tgt.height_m / 2:
                    on.append(hid)
        out[tgt.id] = on
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        data = load_config_data(DEMO)
        ids = field_selection(load_config(DEMO), 12)  # the demo's field
        plant = SimulatedPlant(data, Path(tmp) / "plant", heliostat_ids=ids, source=str(DEMO))
        cfg = plant.cfg
        hid = plant.ids[0]
        aim = nominal_aims(cfg, [hid])[0]
        plant.hidden[hid].controller.move_abs(aim.az_steps, aim.el_steps)
        with plant.clock.frozen(advance_s=1000.0):  # the move ends, every heliostat stands still
            pass
        ours_cam = PlantCamera(plant, cfg, seed=0, perspective=True)
        peer_cam = PlantCamera(plant, cfg, seed=0, perspective=True)
        peer_cam.sim.sensors = tuple(dataclasses.replace(s, shot="poisson") for s in peer_cam.sim.sensors)
        beams = {t.id: plant.safety.on_target(t.id) for t in cfg.targets}
        if beams != previous_sample(plant):
            raise SystemExit("bench_sim_speed: the monitor and its peer disagree")
        capture, capture_peer = cpu_ms(ours_cam.capture, args.runs), cpu_ms(peer_cam.capture, args.runs)
        sample, sample_peer = (cpu_ms(plant.safety.sample, args.runs * 10),
                               cpu_ms(lambda: previous_sample(plant), args.runs * 10))

        def sample_all_moving() -> None:  # every heliostat's pose recomputed, as during slews
            for hh in plant.hidden.values():
                hh.pose_cache = None
            plant.safety.sample()

        moving = cpu_ms(sample_all_moving, args.runs * 10)
    print(json.dumps({
        "capture_ms": round(capture, 2),
        "capture_poisson_sensor_ms": round(capture_peer, 2),
        "capture_speedup": round(capture_peer / capture, 2),
        "safety_sample_ms": round(sample, 3),
        "safety_sample_per_target_recompute_ms": round(sample_peer, 3),
        "safety_sample_speedup": round(sample_peer / sample, 2),
        "safety_sample_all_moving_ms": round(moving, 3),
        "safety_sample_all_moving_speedup": round(sample_peer / moving, 2),
        "sensor_shot_noise": ours_cam.sim.sensors[0].shot,
        "heliostats": len(plant.ids),
        "targets": len(cfg.targets),
        "beams_on_targets": beams,
        "shape": list(ours_cam.grid.shape),
        "runs": args.runs,
        "timer": "thread CPU time, median",
        "cpu_count": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }))


if __name__ == "__main__":
    main()
