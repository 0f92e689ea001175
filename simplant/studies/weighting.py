"""The weighting-function study (HDR paper Fig. 13) on the simulated double-CCD camera: how much
each weighting function lets the beam centroid wander between pairs of one fixed scene.
``heliocal report weighting`` runs it; see that command for the procedure and outputs."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.imaging.beam import analyze
from controller.imaging.hdr import HdrMerger
from controller.imaging.weights import NAMES
from controller.io.images import pyplot, save_figure, write_atomic
from simplant.devices.camera import SimulatedCamera
from simplant.optics import MirrorSurface, TargetGrid, render_spot

THRESHOLDS = tuple(round(0.45 + 0.05 * i, 2) for i in range(10))
TARGET_PX = 200  # target window side in pixels; the frame adds a dark border around it
WINDOW_M = 3.0  # target window side in metres, around the target centre
PSF_SIGMA_PX = 1.0  # camera point-spread function (Gaussian sigma)
BORDER_PX = 28
# Scene brightness: HIGH saturates in the beam core, LOW peaks at this fraction of its range.
LOW_PEAK_FRACTION = 0.8
AMBIENT_FRACTION = 0.04  # diffuse light on the target, as a fraction of the beam peak


@dataclass(frozen=True)
class WeightingStudy:
    """Result of :func:`run_study`. Per weighting name: ``rms_px`` and ``bias_px`` (one value per
    threshold, px) and ``centroids`` (pairs, thresholds, 2) as (x = column, y = row) px;
    ``first_pair`` is (LOW, HIGH, raised-cosine HDR) of the first capture, ``frame`` the
    noise-free irradiance (counts/s at unit gain) and ``mask`` the target mask."""

    thresholds: list[float]
    rms_px: dict[str, list[float]]
    bias_px: dict[str, list[float]]
    centroids: dict[str, np.ndarray]
    first_pair: tuple[np.ndarray, np.ndarray, np.ndarray]
    mergers: dict[str, HdrMerger]
    frame: np.ndarray
    mask: np.ndarray


def _source(cfg, source_id: str | None):
    if source_id:
        return cfg.light_source(source_id)
    return next((s for s in cfg.light_sources if s.kind == "sun"), cfg.light_source())


def _scene(cfg, heliostat_id: str | None, source_id: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance frame (relative, peak 1) and target mask of the study scene."""
    import cv2

    h = cfg.heliostat(heliostat_id) if heliostat_id else cfg.heliostats[0]
    target = cfg.target()
    src = _source(cfg, source_id)
    pos = np.asarray(h.position_enu_m, dtype=float)
    centre = np.asarray(target.center_enu_m, dtype=float)
    if src.kind == "lamp":
        src_vec = np.asarray(src.position_enu_m, dtype=float)
        to_src = (src_vec - pos) / np.linalg.norm(src_vec - pos)
        diameter = src.diameter_m / float(np.linalg.norm(src_vec - pos))
        is_dir = False
    else:  # a fixed, high sun in the south (the study needs one scene, not a date)
        to_src = np.array([0.0, -0.5, 1.0]) / np.sqrt(1.25)
        src_vec, diameter, is_dir = to_src, src.angular_diameter_mrad * 1e-3, True
    to_aim = (centre - pos) / np.linalg.norm(centre - pos)
    normal = (to_src + to_aim) / np.linalg.norm(to_src + to_aim)
    base = TargetGrid.from_target(target, (TARGET_PX, TARGET_PX))
    side = min(WINDOW_M, target.width_m, target.height_m)
    grid = TargetGrid(base.center, base.normal, base.u_axis, base.v_axis, side, side, base.shape)
    mirror = MirrorSurface.from_config(h.mirror)
    rng = np.random.default_rng(12345)
    # Many rays, then the camera's point-spread function: a smooth, fixed scene.
    spot = sum(render_spot(pos, normal, src_vec, diameter, mirror, grid, source_is_direction=is_dir,
                           rng=rng, n_rays=500_000) for _ in range(4))
    spot = cv2.GaussianBlur(spot, (0, 0), PSF_SIGMA_PX)
    spot = spot / spot.max()
    frame = np.zeros((TARGET_PX + 2 * BORDER_PX,) * 2)
    mask = np.zeros(frame.shape, dtype=bool)
    inner = (slice(BORDER_PX, BORDER_PX + TARGET_PX),) * 2
    frame[inner] = spot + AMBIENT_FRACTION
    mask[inner] = True
    return frame, mask


def _centroid(img: np.ndarray, threshold: float, mask: np.ndarray) -> tuple[float, float]:
    return analyze(img, threshold, background="none", mask=mask).centroid_px


def run_study(cfg, pairs: int, seed: int, heliostat_id: str | None = None, progress=None,
              source_id: str | None = None, low_peak: float = LOW_PEAK_FRACTION) -> WeightingStudy:
    """Capture ``pairs`` pairs of the fixed scene, merge each with every weighting and centroid
    the HDR image at every threshold; ``progress()`` is called once per pair."""
    frame, mask = _scene(cfg, heliostat_id, source_id)
    cam_cfg = cfg.camera
    camera = SimulatedCamera(cam_cfg, lambda: frame, seed=seed)
    t_low, t_high = camera.exposures
    # Peak irradiance so that LOW's core reaches ``low_peak`` of its linear range.
    span = camera.sensors[0].span
    scale = low_peak * span / (t_low * camera.sensors[0].gain)
    camera = SimulatedCamera(cam_cfg, lambda: frame, seed=seed, irradiance_scale=scale)
    crf = camera.true_crf()
    mergers = {w: HdrMerger.from_camera_config(cam_cfg, crf, w, exposures=(t_low, t_high)) for w in NAMES}
    cents = {w: np.zeros((pairs, len(THRESHOLDS), 2)) for w in NAMES}
    first = None
    for i in range(pairs):
        pair = camera.capture()
        if first is None:
            first = (pair.low, pair.high, mergers["raised-cosine"].merge(pair.low, pair.high))
        for w, m in mergers.items():
            hdr = m.merge(pair.low, pair.high)
            for j, thr in enumerate(THRESHOLDS):
                cents[w][i, j] = _centroid(hdr, thr, mask)
        if progress is not None:
            progress()
    rms = {w: np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=2), axis=0)) for w, c in cents.items()}
    # Centroid of the noise-free irradiance at each threshold: the truth the means are biased from.
    truth = np.array([_centroid(frame, thr, mask) for thr in THRESHOLDS])
    bias = {w: np.linalg.norm(c.mean(axis=0) - truth, axis=1) for w, c in cents.items()}
    return WeightingStudy(list(THRESHOLDS), {w: rms[w].tolist() for w in NAMES},
                          {w: bias[w].tolist() for w in NAMES}, cents, first, mergers, frame * scale, mask)


def write_plots(out: Path, study: WeightingStudy) -> None:
    """``rms_vs_threshold.png``, ``weighting_functions.png`` and ``profiles.png`` in ``out``."""
    plt = pyplot()
    thr = study.thresholds
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for w, r in study.rms_px.items():
        ax.plot(thr, r, marker="o", ms=3, lw=2.2 if w in ("raised-cosine", "noise-optimal") else 1.2, label=w)
    ax.set_xlabel("threshold (fraction of peak)")
    ax.set_ylabel("centroid RMS distance to mean (px)")
    ax.set_title("Centroid repeatability vs threshold (cf. HDR paper Fig. 13)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "rms_vs_threshold.png", dpi=110)

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    z = np.arange(256)
    for w, m in study.mergers.items():
        wt = m.weights[0]
        ax.plot(z, wt / wt.max(), lw=2.2 if w == "raised-cosine" else 1.2, label=w)
    ax.set_xlabel("pixel value z (counts)")
    ax.set_ylabel("weight w(z) / max")
    ax.set_title("Weighting functions, 8-bit, dark offset 8 (cf. Figs. 3 and 6)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, out / "weighting_functions.png", dpi=110)

    low, high, hdr = study.first_pair
    row = int(np.argmax(hdr.max(axis=1)))
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(low[row], label="LOW (counts)", lw=1)
    ax.plot(high[row], label="HIGH (counts)", lw=1)
    ax.set_xlabel("column x (px)")
    ax.set_ylabel("pixel value (counts)")
    ax2 = ax.twinx()
    ax2.plot(hdr[row], color="k", lw=1.5, label="HDR (raised-cosine)")
    ax2.set_ylabel("HDR irradiance (exposure value / s)")
    ax.set_title(f"Profiles along row {row} (cf. Figs. 9 and 12)")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, out / "profiles.png", dpi=110)


def write_csv(out: Path, study: WeightingStudy) -> None:
    """``weighting_study.csv`` in ``out`` (columns in the command's docstring)."""
    def writer(tmp: Path) -> None:
        with tmp.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["weighting", "threshold", "rms_px", "bias_px", "mean_x_px", "mean_y_px", "pairs"])
            for name, r in study.rms_px.items():
                c = study.centroids[name]
                for j, thr in enumerate(study.thresholds):
                    mx, my = c[:, j].mean(axis=0)
                    w.writerow([name, f"{thr:.2f}", f"{r[j]:.5f}", f"{study.bias_px[name][j]:.5f}",
                                f"{mx:.4f}", f"{my:.4f}", c.shape[0]])
    write_atomic(out / "weighting_study.csv", writer)


