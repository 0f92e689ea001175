"""Benchmark of the HDR merge: our (z1, z2) table gather vs OpenCV MergeRobertson / MergeDebevec.

Prints one JSON object: {"ours_ms", "opencv_robertson_ms", "opencv_debevec_ms",
"speedup_vs_robertson", ...}, medians over --runs runs of one 1024x768 pair from the simulated
sensors. OpenCV gets 3-channel images, float32 times and the explicit response (its HDR code
gives wrong values without all three). Extra keys: minima, table build time, render_spot time
for a 256x256 grid, thread settings and load average, so numbers can be compared across machines.

Usage: .venv/bin/python benchmarks/bench_merge.py [--runs 30] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import cv2
import numpy as np

from controller.imaging.crf import Crf
from controller.imaging.hdr import HdrMerger
from simplant.devices.sensor import SensorModel, knee_response
from simplant.optics import MirrorSurface, TargetGrid, render_spot


def timings_ms(fn, runs: int) -> tuple[float, float]:
    """(median, minimum) wall time in ms; the minimum shows what a quiet machine does."""
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3, min(times) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1 = one core)")
    args = ap.parse_args()
    cv2.setNumThreads(args.threads)

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:768, 0:1024]
    scene = 60000.0 * np.exp(-((x - 500.0) ** 2 + (y - 380.0) ** 2) / (2 * 90.0**2)) + 500.0
    s1 = SensorModel(response=knee_response(0.15))
    s2 = SensorModel(response=knee_response(0.25), gain=1.03)
    t = (0.010, 0.020)
    low, high = s1.expose(scene, t[0], rng), s2.expose(scene, t[1], rng)
    crf = Crf.from_tables([s1.inverse_response(), s2.inverse_response()])

    t0 = time.perf_counter()
    merger = HdrMerger(t, crf, "raised-cosine", 8.0)
    build_ms = (time.perf_counter() - t0) * 1e3
    ours, ours_min = timings_ms(lambda: merger.merge(low, high), args.runs)

    imgs = [cv2.merge([z, z, z]) for z in (low, high)]
    times = np.asarray(t, dtype=np.float32)
    resp = np.repeat(np.maximum(crf.inverse(0), 1e-3).astype(np.float32)[:, None, None], 3, axis=2)
    rob = cv2.createMergeRobertson()
    deb = cv2.createMergeDebevec()
    rob_ms, rob_min = timings_ms(lambda: rob.process(imgs, times, resp), args.runs)
    deb_ms, _ = timings_ms(lambda: deb.process(imgs, times, resp), args.runs)

    grid = TargetGrid(np.array([0.0, 0.0, 30.0]), np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]),
                      np.array([0.0, 0.0, -1.0]), 8.0, 7.0, (256, 256))
    helio = np.array([-22.5, 40.0, 2.0])
    lamp = np.array([0.0, 5.0, 55.0])
    s = (lamp - helio) / np.linalg.norm(lamp - helio)
    a = (grid.center - helio) / np.linalg.norm(grid.center - helio)
    n = (s + a) / np.linalg.norm(s + a)
    mirror = MirrorSurface(3.2, 2.56, 53.8, 1.5)
    spot_ms, _ = timings_ms(lambda: render_spot(helio, n, lamp, 0.005, mirror, grid), max(5, args.runs // 3))

    print(json.dumps({
        "ours_ms": round(ours, 3),
        "opencv_robertson_ms": round(rob_ms, 3),
        "opencv_debevec_ms": round(deb_ms, 3),
        "speedup_vs_robertson": round(rob_ms / ours, 1),
        "ours_min_ms": round(ours_min, 3),
        "opencv_robertson_min_ms": round(rob_min, 3),
        "table_build_ms": round(build_ms, 1),
        "render_spot_256_ms": round(spot_ms, 2),
        "shape": [768, 1024],
        "runs": args.runs,
        "opencv_threads": cv2.getNumThreads(),
        "cpu_count": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }))


if __name__ == "__main__":
    main()
