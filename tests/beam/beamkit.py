"""Helpers of the beam-analysis / recognition tests: synthetic spots, the CLI runner, and the
projection of PAINT focal spots (WGS84) into the target image."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares

REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "tests" / "data" / "real"  # the real Jülich records (see its README)
PAINT = REAL / "paint"
TOWER = REAL / "aa39" / "tower-measurements.json"

# The empty-target photos sorted by name; every third (index 2, 5, 8, …) is held out: never
# looked at while the presence statistic and the centroid's settings were chosen.
EMPTY = sorted((REAL / "utis-empty").glob("*.png"))
HELD_OUT = [p for i, p in enumerate(EMPTY) if i % 3 == 2]
TUNING = [p for i, p in enumerate(EMPTY) if i % 3 != 2]

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563


def heliocal(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run the installed CLI as a user would; returns the completed process (text mode)."""
    return subprocess.run([sys.executable, "-m", "controller.cli", *args], capture_output=True, text=True,
                          cwd=cwd or REPO, timeout=300)


def _ecef(lat_deg: float, lon_deg: float, h: float) -> np.ndarray:
    e2 = WGS84_F * (2 - WGS84_F)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.array([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                     (n * (1 - e2) + h) * np.sin(lat)])


def _enu(p, ref) -> np.ndarray:
    lat, lon = np.radians(ref[0]), np.radians(ref[1])
    r = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                  [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                  [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
    return r @ (_ecef(*p) - _ecef(*ref))


def project_to_image(point_wgs84, target: dict, size_px: int = 256) -> np.ndarray:
    """(x, y) pixel of a WGS84 point on a PAINT target image (x = column, left = east).

    The four measured corners span the image; the point's bilinear coordinates (s, t) in
    [0, 1]^2 are found by least squares in local ENU and scaled by the image size (x = s N,
    y = t N). This is the projection under which UTIS lies within ~0.6 px of the flux centroid
    (README of tests/data/real).
    """
    c = target["coordinates"]
    ref = c["center"]
    ul, ur, ll, lr = (_enu(c[k], ref) for k in ("upper_left", "upper_right", "lower_left", "lower_right"))
    p = _enu(point_wgs84, ref)

    def resid(st):
        s, t = st
        return ul * (1 - s) * (1 - t) + ur * s * (1 - t) + ll * (1 - s) * t + lr * s * t - p

    return least_squares(resid, [0.5, 0.5]).x * size_px


def paint_samples() -> list[str]:
    return sorted(p.name.split("-")[0] for p in PAINT.glob("*-cropped.png"))


def main_lobe(sample: str) -> tuple[np.ndarray, np.ndarray]:
    """UTIS's main lobe of PAINT ``sample`` (the most energetic 8-connected part of its flux
    image) scaled to peak 1, and its intensity centroid (x, y) px."""
    flux = cv2.imread(str(PAINT / f"{sample}-flux.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    _, labels = cv2.connectedComponents((flux > 0).astype(np.uint8), connectivity=8)
    energy = np.bincount(labels.ravel(), weights=flux.ravel())
    energy[0] = -1.0
    w = np.where(labels == int(np.argmax(energy)), flux, 0.0)
    yy, xx = np.indices(w.shape)
    return w / w.max(), np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()


def real_spots() -> list[tuple[np.ndarray, np.ndarray]]:
    """(spot, true centroid (x, y) px) for each PAINT sample: UTIS's main lobe at the brightness
    it has in its own photo (its smoothed excess there), to lay onto empty-target photos."""
    from controller.imaging.presence import detect_beam
    from controller.io.images import read_image

    out = []
    for sample in paint_samples():
        spot, truth = main_lobe(sample)
        own = detect_beam(read_image(PAINT / f"{sample}-cropped.png"))
        out.append((float(own.smoothed.max() - own.floor) * spot, truth))
    return out


def gaussian(shape, x0, y0, sx, sy=None, amp=1.0) -> np.ndarray:
    """Sampled 2-D Gaussian at pixel centres; x = column, y = row."""
    sy = sx if sy is None else sy
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    return amp * np.exp(-0.5 * (((xx - x0) / sx) ** 2 + ((yy - y0) / sy) ** 2))


def skewed_blob(shape=(120, 160), seed=0) -> np.ndarray:
    """An asymmetric grey spot (sum of three Gaussians), so that phi_3..phi_7 are not ~0."""
    rng = np.random.default_rng(seed)
    img = np.zeros(shape)
    for _ in range(3):
        img += gaussian(shape, rng.uniform(0.35, 0.65) * shape[1], rng.uniform(0.35, 0.65) * shape[0],
                        rng.uniform(4, 14), rng.uniform(4, 14), rng.uniform(0.5, 1.0))
    return img


def cli(capsys, *args: str) -> tuple[int, str, str]:
    """Run ``heliocal ARGS`` in-process (same parser and error handling as the console script)."""
    from controller.cli import main

    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err
