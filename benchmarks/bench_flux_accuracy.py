"""PHLUX accuracy on synthetic truth and the time of one flux map; prints one JSON object.

Renders (with the test renderers of tests/flux/conftest.py: limb-darkened Sun, Lambertian
two-lobed beam, 8x8-supersampled footprints, simplant.devices.sensor.SensorModel 8-bit) a sun
image (DNI 900 W/m², ND 0.01) and target images at several distances / view angles, and
reports the flux-map RMS error over the beam (pixels with truth >= 10 % of peak, RMS / mean),
the error of the power in the frame, and the sun-radius error; then times find_sun_disc +
irradiance_from_sun_image on a 1024x768 frame. Also the tube-panel power error (uniform and
beam-lit surface) for tube radii of 6, 12 and 20 px.

    .venv/bin/python benchmarks/bench_flux_accuracy.py
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

from controller.flux import phlux
from controller.flux.sun_disc import find_sun_disc

HERE = Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("flux_render", HERE.parent / "tests" / "flux" / "conftest.py")
render = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = render  # dataclasses look their module up
spec.loader.exec_module(render)

DNI, RHO, T_SUN, T_EXP = 900.0, 0.85, 0.01, 1e-3


def accuracy(seeds: int = 5) -> list[dict]:
    cam = render.Camera()
    field, power = render.gaussian_beam()
    rows = []
    for distance, view_deg in [(70.0, 0.0), (100.0, 0.0), (150.0, 40.0), (120.0, 60.0)]:
        theta = np.radians(view_deg)
        truth = cam.truth(field, distance, theta)
        beam = truth >= 0.1 * truth.max()
        # the frame may cut the beam's tails: compare with the power inside it
        in_frame = float(truth.sum() * (distance * cam.ifov) ** 2 / np.cos(theta))
        rms, perr, rerr = [], [], []
        for seed in range(seeds):
            rng = np.random.default_rng(seed)
            sun = cam.expose(cam.sun_rate(DNI, T_SUN), T_EXP, rng)
            rate = cam.target_rate(field, RHO, distance, theta)
            img = cam.expose(rate, T_EXP, rng).astype(float) - cam.expose(0 * rate, T_EXP, rng)
            disc = find_sun_disc(sun)
            e = phlux.irradiance_from_sun_image(
                img, disc.sum_counts, disc.radius_px, DNI, RHO, sun_transmittance=T_SUN
            )
            rms.append(np.sqrt(np.mean((e[beam] - truth[beam]) ** 2)) / truth[beam].mean())
            p = phlux.total_power_w(e, phlux.pixel_area_m2(distance, theta, disc.radius_px))
            perr.append(p / in_frame - 1)
            rerr.append(disc.radius_px - cam.sun_radius_px)
        rows.append(
            {
                "distance_m": distance,
                "view_angle_deg": view_deg,
                "seeds": seeds,
                "beam_fraction_in_frame": in_frame / power,
                "rms_over_beam_max": float(max(rms)),
                "power_error_max_abs": float(np.max(np.abs(perr))),
                "sun_radius_error_px_mean": float(np.mean(rerr)),
            }
        )
    return rows


def tubes() -> list[dict]:
    """Power error on a panel of 4 touching tubes (outer edges on pixel boundaries) at 100 m, for
    uniform surface irradiance (500 kW/m²) and a beam along the line of sight (E_b cos φ)."""
    cam = render.Camera()
    rows = []
    for radius in (6.0, 12.0, 20.0):
        rng = np.random.default_rng(1)
        axes = 30.5 + radius + 2.0 * radius * np.arange(4)
        xx, yy = cam.grid()
        nearest = axes[np.argmin(np.abs(xx[..., None] - axes), axis=-1)]
        cos_phi = np.sqrt(np.clip(1.0 - ((xx - nearest) / radius) ** 2, 0.0, 1.0))
        lit = (np.abs(xx - nearest) < radius) & (yy > 19.5) & (yy < 179.5)
        disc = find_sun_disc(cam.expose(cam.sun_rate(DNI, T_SUN), T_EXP, rng))
        area = phlux.tube_panel_area_map(cam.shape, axes, radius, 100.0, disc.radius_px)
        r_m = phlux.tube_radius_m(radius, 100.0, cam.sun_radius_px)
        length = 160 * 100.0 * cam.ifov
        row = {"tube_radius_px": radius}
        for case, e_s, per_tube in (
            ("uniform", np.where(lit, 500e3, 0.0), np.pi * r_m),
            ("beam", np.where(lit, 500e3 * cos_phi, 0.0), 2.0 * r_m),
        ):
            rate = cam.k * RHO * cam.bin(e_s) / np.pi * cam.omega_px
            img = cam.expose(rate, T_EXP, rng).astype(float) - cam.expose(0 * rate, T_EXP, rng)
            e = phlux.irradiance_from_sun_image(
                img, disc.sum_counts, disc.radius_px, DNI, RHO, sun_transmittance=T_SUN
            )
            row[f"{case}_power_error"] = phlux.total_power_w(e, area) / (500e3 * 4 * length * per_tube) - 1
        rows.append(row)
    return rows


def timing(repeat: int = 5) -> dict:
    cam = render.Camera(shape=(768, 1024), sun_radius_px=60.0)
    rng = np.random.default_rng(0)
    sun = cam.expose(cam.sun_rate(DNI, T_SUN), T_EXP, rng)
    img = rng.integers(8, 200, size=cam.shape).astype(float)
    best_disc, best_map = np.inf, np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        disc = find_sun_disc(sun)
        t1 = time.perf_counter()
        phlux.irradiance_from_sun_image(img, disc.sum_counts, disc.radius_px, DNI, RHO)
        t2 = time.perf_counter()
        best_disc, best_map = min(best_disc, t1 - t0), min(best_map, t2 - t1)
    return {
        "frame": "1024x768",
        "sun_radius_px": 60.0,
        "find_sun_disc_ms": 1e3 * best_disc,
        "irradiance_map_ms": 1e3 * best_map,
    }


if __name__ == "__main__":
    print(json.dumps({"accuracy": accuracy(), "tubes": tubes(), "timing": timing()}))
