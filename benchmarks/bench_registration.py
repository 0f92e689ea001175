"""Benchmark of registration in the beam chain: per pair, rectify both exposures + HDR merge +
beam analysis, against merge + analysis without registration, at 1024x768.

Prints one JSON object: {"with_registration_ms", "without_registration_ms", "ratio",
"rectify_pair_ms", "maps_build_ms", "register_ms", ...}, medians over --runs runs. The two
sensors get their own camera models (a 0.3 px misregistration between them) and the pair is
rectified exactly as the beam chain does it (``CameraRegistration.rectify``: bilinear, HIGH's
clipped core kept clipped); the remap tables are built once per registration
(``maps_build_ms`` per sensor, not per pair), as a campaign does at its start;
``register_ms`` is one intrinsics+pose fit on 99 fiducials, ``register_step_ms`` the campaign's
per-start work besides its two captures: fiducial detection, a pose fit and the remap tables
for both sensors (9 fiducials).

Usage: .venv/bin/python benchmarks/bench_registration.py [--runs 30] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from types import SimpleNamespace

import cv2
import numpy as np
from bench_merge import timings_ms  # this folder: the same timing for both benchmarks

from controller.calibration.cycle.registration_step import CameraRegistration
from controller.devices.camera import FramePair
from controller.geometry.target_frame import TargetFrame
from controller.imaging.beam import analyze
from controller.imaging.crf import Crf
from controller.imaging.fiducials import detect_fiducials
from controller.imaging.hdr import HdrMerger
from controller.imaging.registration import CameraModel, rectification_maps, register, remap
from simplant.devices.sensor import SensorModel, knee_response

SIZE = (1024, 768)
CENTER = np.array([0.0, 0.0, 130.0])


def camera(shift_px: float) -> CameraModel:
    """A Jülich-like view (60 m north, 28 m below the target centre), shifted by ``shift_px``."""
    c = np.array([2.0, 60.0, 102.0])
    z = (CENTER - c) / np.linalg.norm(CENTER - c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    r = np.vstack([x, np.cross(z, x), z])
    k = np.array([[4700.0, 0, 512.0 + shift_px], [0, 4700.0, 384.0], [0, 0, 1]])
    return CameraModel(k, np.array([-0.3, 0.5, 0, 0, 0]), cv2.Rodrigues(r)[0].ravel(), -r @ c, SIZE)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1 = one core)")
    args = ap.parse_args()
    cv2.setNumThreads(args.threads)

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:SIZE[1], 0:SIZE[0]]
    scene = 60000.0 * np.exp(-((x - 500.0) ** 2 + (y - 380.0) ** 2) / (2 * 90.0**2)) + 500.0
    s1 = SensorModel(response=knee_response(0.15))
    s2 = SensorModel(response=knee_response(0.25), gain=1.03)
    t = (0.010, 0.020)
    low, high = s1.expose(scene, t[0], rng), s2.expose(scene, t[1], rng)
    crf = Crf.from_tables([s1.inverse_response(), s2.inverse_response()])
    merger = HdrMerger(t, crf, "raised-cosine", 8.0)

    frame = TargetFrame.from_config(SimpleNamespace(normal=[0.0, 1.0, 0.0], center_enu_m=CENTER, width_m=8.6,
                                                    height_m=7.2), (SIZE[1], SIZE[0]))
    cam_low, cam_high = camera(0.0), camera(0.3)
    t0 = time.perf_counter()
    maps_low, maps_high = rectification_maps(cam_low, frame), rectification_maps(cam_high, frame)
    maps_ms = (time.perf_counter() - t0) * 1e3 / 2

    s, tt = np.meshgrid(np.linspace(-4.3, 4.3, 11), np.linspace(-3.6, 3.6, 9))
    fid = CENTER + np.column_stack([-s.ravel(), np.zeros(s.size), -tt.ravel()])
    obs = cam_low.project(fid) + rng.normal(0, 0.05, (len(fid), 2))
    reg_ms, _ = timings_ms(lambda: register(fid, obs, SIZE), max(5, args.runs // 3))
    regs = [register(fid, c.project(fid) + rng.normal(0, 0.05, (len(fid), 2)), SIZE, fix_intrinsics=c)
            for c in (cam_low, cam_high)]
    chain_reg = CameraRegistration.build(regs[0], regs[1], frame, len(fid), 8)
    pair = FramePair(low, high, t, 0.0)

    nine = fid[[0, 5, 10, 44, 49, 54, 88, 93, 98]]
    dots = np.zeros((SIZE[1], SIZE[0]))
    for u, v in cam_low.project(nine):
        dots += 150.0 * np.exp(-((x - u) ** 2 + (y - v) ** 2) / (2 * 2.0**2))

    def register_step():
        for c in (cam_low, cam_high):
            px = detect_fiducials(dots, c.project(nine) + 20.0, 100.0)
            r = register(nine, px, SIZE, fix_intrinsics=c)
            rectification_maps(r.model, frame)

    step_ms, _ = timings_ms(register_step, max(3, args.runs // 10))

    def without():
        return analyze(merger.merge(low, high))

    def rectify_pair():
        return chain_reg.rectify(pair)

    def with_reg():
        return analyze(merger.merge(*rectify_pair()))

    plain_ms, plain_min = timings_ms(without, args.runs)
    reg_pair_ms, reg_min = timings_ms(with_reg, args.runs)
    rect_ms, _ = timings_ms(rectify_pair, args.runs)
    plain_rect_ms, _ = timings_ms(lambda: (remap(low, maps_low), remap(high, maps_high)), args.runs)

    print(json.dumps({
        "with_registration_ms": round(reg_pair_ms, 3),
        "without_registration_ms": round(plain_ms, 3),
        "ratio": round(reg_pair_ms / plain_ms, 2),
        "with_registration_min_ms": round(reg_min, 3),
        "without_registration_min_ms": round(plain_min, 3),
        "rectify_pair_ms": round(rect_ms, 3),
        "rectify_pair_plain_remap_ms": round(plain_rect_ms, 3),
        "register_step_ms": round(step_ms, 1),
        "maps_build_ms": round(maps_ms, 1),
        "register_ms": round(reg_ms, 2),
        "shape": [SIZE[1], SIZE[0]],
        "runs": args.runs,
        "opencv_threads": cv2.getNumThreads(),
        "cpu_count": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }))


if __name__ == "__main__":
    main()
