"""Benchmark of the tracking model: fit time for 20 and 200 measurements against a plain scipy
``least_squares`` peer, and the latency of aiming with a model (in process and ``heliocal aim``).

Prints one JSON object:

* ``fit``: per measurement count, the controller's ``fit_model`` (MAP with priors, robust
  IRLS, covariance) and the peer — the same residuals (tangential components of model minus
  measured normal, Eq. 1 of model_fit) minimised by ``scipy.optimize.least_squares`` (LM, the
  same tolerances) with no prior, no robust loop and no covariance, over the terms pointing
  data can see (all but tilt_north, which duplicates el_offset and would leave the peer
  singular). Median and minimum seconds, the ratio ours/peer, and both fits' largest term
  error in units of the controller's σ, so the two are seen to solve the same problem.
* ``aim``: ``model_aim`` per call in process (µs), and the wall time of a ``heliocal aim``
  subprocess on a demo database beside that of ``heliocal --version`` (the interpreter and
  CLI start-up alone). The database is ``--demo-dir``'s ``campaign.db``, or one made once by
  ``heliocal demo --heliostats 1 --nights 0`` in a temporary folder (its time is reported).

Data: synthetic AA39 measurements made by the controller's own model with known terms
(random pose, sun lighting the mirror, spot 50 m down the beam, 0.1 mrad noise).

Usage: .venv/bin/python benchmarks/bench_model.py [--runs 3] [--demo-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from controller.geometry.aiming import reflected_beam
from controller.geometry.design import tangents
from controller.geometry.model.fit import Sample, fit_model, measured_normal
from controller.geometry.model.tracking import (
    NAMES,
    PRIOR_SIGMA_SI,
    TrackingModel,
    model_aim,
    model_mirror_center,
    model_normal,
)
from controller.geometry.paint_io import kinematics_from_properties, read_heliostat_properties, read_towers
from controller.geometry.vectors import azel_to_vector, unit

ROOT = Path(__file__).resolve().parents[1]
AA39 = ROOT / "tests" / "data" / "real" / "aa39"
TRUE = {"az_offset": 8.0, "el_offset": -5.0, "tilt_north": 0.0, "tilt_east": 1.5, "base_yaw": -6.0,
        "non_orthogonality": 1.0, "mirror_offset": 2.0, "az_stroke0": 1.0, "el_stroke0": -1.0,
        "az_pivot_radius": 0.5, "el_pivot_radius": -0.4, "position_e": 20.0, "position_n": -10.0,
        "position_u": 15.0}  # mrad / mm


def synthetic(kin, model: TrackingModel, n: int, rng) -> list[Sample]:
    out = []
    while len(out) < n:
        az, el = rng.uniform(8000, 70000), rng.uniform(5000, 45000)
        sun = rng.normal(size=3)
        sun[2] = abs(sun[2]) + 0.3
        sun = unit(sun)
        normal = model_normal(kin, model, az, el)
        if sun @ normal < 0.3:
            continue
        d = rng.normal(0.0, 1e-4, 3)
        normal = unit(normal + d - (d @ normal) * normal)
        spot = model_mirror_center(kin, model, az, el) + 50.0 * reflected_beam(sun, normal)
        out.append(Sample(sun, az, el, spot))
    return out


def peer_fit(kin, samples: list[Sample], noise_mrad: float) -> np.ndarray:
    """Plain nonlinear least squares of the same residuals: no prior, no robust loop. Returns
    the terms (SI), tilt_north held at 0."""
    from scipy.optimize import least_squares

    free = np.array([n != "tilt_north" for n in NAMES])
    bases = [tangents(measured_normal(kin, TrackingModel.zero(), s)) for s in samples]
    scale = PRIOR_SIGMA_SI[free]  # parameters in units of their typical size: a well-scaled problem

    def res(x: np.ndarray) -> np.ndarray:
        v = np.zeros(len(NAMES))
        v[free] = x * scale
        m = TrackingModel(v)
        return np.concatenate([b @ (model_normal(kin, m, s.az_steps, s.el_steps) - measured_normal(kin, m, s))
                               for s, b in zip(samples, bases, strict=True)]) / (noise_mrad * 1e-3)

    sol = least_squares(res, np.zeros(int(free.sum())), method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    v = np.zeros(len(NAMES))
    v[free] = sol.x * scale
    return v


def timed(fn, runs: int) -> tuple[float, float, object]:
    times, out = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), out


def worst_z(values: np.ndarray, truth: np.ndarray, sigma: np.ndarray) -> float:
    free = np.array([n != "tilt_north" for n in NAMES])
    return float(np.max(np.abs(values - truth)[free] / sigma[free]))


def bench_fit(kin, runs: int) -> dict:
    truth = TrackingModel(np.array([TRUE[n] * 1e-3 for n in NAMES]))
    out = {}
    for n in (20, 200):
        samples = synthetic(kin, truth, n, np.random.default_rng(n))
        ours_med, ours_min, fit = timed(lambda s=samples: fit_model(kin, s, noise_mrad=0.1), runs)
        peer_med, peer_min, peer = timed(lambda s=samples: peer_fit(kin, s, 0.1), runs)
        out[str(n)] = {
            "ours_s": round(ours_med, 3), "ours_min_s": round(ours_min, 3),
            "peer_scipy_lm_s": round(peer_med, 3), "peer_min_s": round(peer_min, 3),
            "ratio_ours_over_peer": round(ours_med / peer_med, 2),
            "identified": len(fit.identified_terms()),
            "ours_worst_error_sigma": round(worst_z(fit.model.values, truth.values, fit.sigma), 2),
            "peer_worst_error_sigma": round(worst_z(peer, truth.values, fit.sigma), 2),
        }
    return out


def bench_aim(kin, towers, runs: int, demo_dir: Path, *, make_demo: bool = False) -> dict:
    model = TrackingModel(np.array([TRUE[n] * 1e-3 for n in NAMES]))
    aim = towers.targets["solar_tower_juelich_upper"].center_enu
    suns = [azel_to_vector(a, e) for a, e in ((120, 30), (160, 55), (200, 45), (240, 20))]
    calls = 50 * len(suns)
    t0 = time.perf_counter()
    for _ in range(50):
        for s in suns:
            model_aim(kin, model, s, aim)
    out: dict = {"model_aim_us_per_call": round((time.perf_counter() - t0) / calls * 1e6, 1), "calls": calls}
    heliocal = shutil.which("heliocal", path=str(Path(sys.executable).parent)) or "heliocal"
    made_s = None
    if make_demo:  # a one-heliostat calibration night of the simulated plant
        t0 = time.perf_counter()
        res = subprocess.run([heliocal, "demo", "--heliostats", "1", "--nights", "0", "--out", str(demo_dir),
                              "--json"], capture_output=True, text=True, timeout=900, check=False)
        made_s = time.perf_counter() - t0
        if res.returncode not in (0, 3):  # 3: the night ended partial, its models are there
            out["cli"] = f"skipped: heliocal demo failed: {res.stderr.strip()[-200:]}"
            return out
    db = demo_dir / "campaign.db"
    if not db.is_file():
        out["cli"] = f"skipped: no campaign.db in {demo_dir} (run: heliocal demo --out DIR --json)"
        return out
    from controller.commands.common import DEFAULT_CONFIG
    from controller.config import load_config
    from controller.storage.db import open_existing

    cfg = load_config(DEFAULT_CONFIG)
    with open_existing(str(db)) as store:
        fitted = [h.id for h in cfg.heliostats if store.latest_model(h.id) is not None]
    hid = fitted[0] if fitted else cfg.heliostats[0].id
    argv = [heliocal, "aim", "--config", str(DEFAULT_CONFIG), "--db", str(db), "--heliostat", hid,
            "--sun-az", "180", "--sun-el", "45", "--json"]
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        res = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
        walls.append(time.perf_counter() - t0)
        if res.returncode != 0:
            out["cli"] = f"failed: {res.stderr.strip()[:200]}"
            return out
    startup = []
    for _ in range(runs):  # the interpreter and CLI start-up alone, for scale
        t0 = time.perf_counter()
        subprocess.run([heliocal, "--version"], capture_output=True, timeout=60, check=False)
        startup.append(time.perf_counter() - t0)
    out["cli_aim_wall_s"] = round(statistics.median(walls), 3)
    out["cli_version_wall_s"] = round(statistics.median(startup), 3)
    out["cli_aim_heliostat_has_model"] = json.loads(res.stdout)["model"] is not None
    out["demo_made_s"] = None if made_s is None else round(made_s, 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--demo-dir", type=Path, default=None,
                    help="output folder of 'heliocal demo' (its database is used for 'heliocal aim')")
    args = ap.parse_args()
    towers = read_towers(AA39 / "tower-measurements.json")
    kin = kinematics_from_properties(read_heliostat_properties(AA39 / "AA39-heliostat-properties.json"),
                                     towers.origin_wgs84, "AA39")
    if args.demo_dir is not None:
        aim = bench_aim(kin, towers, max(args.runs, 5), args.demo_dir)
    else:  # a demo database of our own, removed afterwards
        with tempfile.TemporaryDirectory(prefix="bench-model-demo-") as tmp:
            aim = bench_aim(kin, towers, max(args.runs, 5), Path(tmp), make_demo=True)
    print(json.dumps({
        "fit": bench_fit(kin, args.runs),
        "aim": aim,
        "runs": args.runs,
        "load_average": [round(v, 2) for v in os.getloadavg()],
        "cpus": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
