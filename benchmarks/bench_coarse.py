"""The coarse correction in the closed loop, against centroid only on the same plant (JSON on stdout).

    .venv/bin/python benchmarks/bench_coarse.py [--seed 0] [--threshold 0.5] [--tracking-error 3]
                                                [--heliostats 12] [--standby-offset M]

Runs the demo's first calibration (embedded simulated plant, demo config, ``--nights 0``) twice
on the same seed: with ``calibration.coarse_correction: T`` and with ``null`` (the peer,
centroid only). ``--tracking-error`` is the scale of the plant's hidden per-heliostat errors
(mrad, :class:`simplant.settings.SimulationSettings`; the demo's 3 keeps every first spot in
view; larger scales, as on an uncalibrated field, put first spots at the view's edge). Per
variant: runs, calibrated, failed (with causes), ``iterations_mean`` (measurements per
heliostat), ``corrections_mean`` (corrective moves per heliostat, each followed by one more
capture, so it counts the looks at clipped spots), ``clipped_first_looks``, ``applied`` (runs
with a coarse move), for the runs whose first look was clipped (``clipped_runs``) their
iterations and the measured error of the first measurement after the clipped look(s), and the
truth's final error (closed loop, the plant's hidden state). The ratios are with / centroid only.
``clipped_centre_on_shifted_spots``: the estimator alone, open loop, on the run's own spots
shifted to the view's edges (:func:`shifted_spots`).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from controller.calibration.cycle.beam_chain import BeamChain
from controller.commands.simulated import simulated_campaign
from controller.config import load_config
from controller.devices.camera import FramePair
from controller.imaging.background import subtract_background
from controller.imaging.beam import analyze
from controller.imaging.centroid import energy_centroid
from controller.imaging.clipped_spot import clipped_centre
from controller.io.images import read_image
from controller.storage.db import open_existing
from simplant.plant import field_selection
from simplant.settings import SimulationSettings

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "demo.yaml"


def one(tmp: Path, name: str, threshold: float | None, args: argparse.Namespace) -> dict:
    seed, tracking_error, heliostats = args.seed, args.tracking_error, args.heliostats
    data = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
    data["calibration"]["coarse_correction"] = threshold
    if args.standby_offset is not None:
        data["calibration"]["standby_offset_m"] = args.standby_offset
    out = tmp / name
    out.mkdir()
    path = out / "config.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    cfg = load_config(path)
    ids = field_selection(cfg, heliostats)
    settings = SimulationSettings(seed=seed, tracking_error_mrad=tracking_error)
    t0 = time.perf_counter()
    s, sim = simulated_campaign(cfg, str(path), out, out / "campaign.db", ids, settings, f"coarse-{name}",
                                library_dir=tmp)
    c = s["coarse_correction"]
    cid = sim.result.campaign_id
    with open_existing(out / "campaign.db") as store:
        runs = store.runs(cid)
        first = {}  # run id -> error of its first measurement (measured, mrad)
        for m in store.measurements(cid):
            first.setdefault(m.run_id, m.error_mrad)
        clipped = [r for r in runs if (moves := store.corrections(r.id)) and moves[0].iteration == 0]
    causes: dict[str, int] = {}
    for r in runs:
        if r.status == "failed":
            key = (r.fault_cause or "?").split(":")[0]
            causes[key] = causes.get(key, 0) + 1
    return {"threshold": threshold, "runs": len(runs), "calibrated": s["calibrated"],
            "failed": s["failed"], "failed_causes": causes, "applied": c["applied"],
            "clipped_first_looks": c["clipped_first_looks"], "iterations_mean": c["iterations_mean"],
            "corrections_mean": c["corrections_mean"],
            "iterations_by_heliostat": {r.heliostat_id: r.iterations for r in runs},
            "clipped_runs": {"heliostats": [r.heliostat_id for r in clipped],
                             "iterations": [r.iterations for r in clipped],
                             "first_measured_error_mrad": [_round(first.get(r.id)) for r in clipped]},
            "error_after_mrad": s["error_after_mrad"], "wall_s": round(time.perf_counter() - t0, 1),
            "_cfg": cfg, "_out": out}


DEPTHS = (0.9, 0.6, 0.3, 0.0)  # centre inside the edge, fraction of the spot's half extent


def shifted_spots(out: Path, cfg, threshold: float) -> dict:
    """The clipped-centre estimate on the run's own spots, against their known centres.

    Every measured spot in full view (the centroid-only run's saved frame pairs, merged and
    background-subtracted as the beam chain does) is shifted towards each edge of the view so
    that its energy centroid lies ``depth`` × its half extent inside the edge (0: on the edge),
    with fresh noise of the image's own σ; then the clipped spot's energy centroid and its
    estimated centre (:func:`clipped_centre`) are compared with where the centroid was moved
    to. Per depth: n, mean/median error (px) of the visible centroid and of the estimate, and
    the share of confident estimates (≥ ``threshold``) and their errors."""
    chain = BeamChain(cfg)
    thr = cfg.calibration.centroid_threshold
    rng = np.random.default_rng(0)
    spots = []
    with open_existing(out / "campaign.db") as store:
        for m in store.measurements():
            imgs = {i.kind: i for i in store.images(m.id)}
            if {"low", "high"} <= set(imgs):
                pair = FramePair(read_image(imgs["low"].path), read_image(imgs["high"].path),
                                 tuple(imgs["low"].exposures), 0.0, {})
                hdr = chain.merge(pair)
                r = analyze(hdr, threshold=chain.threshold, background="auto")
                sig = subtract_background(hdr, r.background)
                c = energy_centroid(sig, thr)
                if not c.clipped and c.total > 0:
                    spots.append((sig, c, r.background.noise))
    rows, cols = spots[0][0].shape if spots else (0, 0)
    res: dict = {}
    for depth in DEPTHS:
        errs = []
        for sig, c, noise in spots:
            ys, xs = np.nonzero(sig > thr * sig.max())
            for edge in ("left", "right", "top", "bottom"):
                half = (np.ptp(xs) if edge in ("left", "right") else np.ptp(ys)) / 2.0
                dx = {"left": depth * half - c.x, "right": cols - 1 - depth * half - c.x}.get(edge, 0.0)
                dy = {"top": depth * half - c.y, "bottom": rows - 1 - depth * half - c.y}.get(edge, 0.0)
                moved = cv2.warpAffine(sig, np.float32([[1, 0, dx], [0, 1, dy]]), (cols, rows), borderValue=0)
                moved = moved + rng.normal(0.0, noise, moved.shape).astype(np.float32)
                v = energy_centroid(moved, thr)
                if not v.clipped or not v.total > 0:
                    continue
                est, conf = clipped_centre(moved, thr, tuple(v.clipped), (v.x, v.y))
                truth = (c.x + dx, c.y + dy)
                e0 = float(np.hypot(v.x - truth[0], v.y - truth[1]))
                e1 = float(np.hypot(est[0] - truth[0], est[1] - truth[1])) if est is not None else e0
                errs.append((e0, e1, conf))
        a = np.array(errs) if errs else np.zeros((0, 3))
        sure = a[a[:, 2] >= threshold]
        res[str(depth)] = {"n": len(a), "centroid_error_px": _stats(a[:, 0]),
                           "estimate_error_px": _stats(a[:, 1]),
                           "confident_share": _r1(100.0 * len(sure) / len(a)) if len(a) else None,
                           "confident": {"centroid_error_px": _stats(sure[:, 0]),
                                         "estimate_error_px": _stats(sure[:, 1])}}
    return {"spots": len(spots), "by_depth": res}


def _r1(v: float) -> float:
    return round(float(v), 1)


def _stats(v: np.ndarray) -> dict:
    return {"mean": _r1(v.mean()), "median": _r1(np.median(v))} if v.size else {"mean": None, "median": None}


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threshold", type=float, default=0.5, help="calibration.coarse_correction of the run")
    ap.add_argument("--tracking-error", type=float, default=3.0, help="hidden error scale, mrad")
    ap.add_argument("--heliostats", type=int, default=12)
    ap.add_argument("--standby-offset", type=float, default=None,
                    help="calibration.standby_offset_m (m; default: the demo's)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        with_ = one(Path(tmp), "with", args.threshold, args)
        peer = one(Path(tmp), "centroid-only", None, args)
        cfg = with_.pop("_cfg")
        estimator = shifted_spots(peer.pop("_out"), cfg, args.threshold)
        with_.pop("_out"), peer.pop("_cfg")

    def ratio(key: str) -> float | None:
        return round(with_[key] / peer[key], 3) if with_[key] is not None and peer[key] else None

    print(json.dumps({"seed": args.seed, "tracking_error_mrad": args.tracking_error,
                      "standby_offset_m": args.standby_offset,
                      "heliostats": args.heliostats, "coarse": with_, "centroid_only": peer,
                      "ratio_corrections": ratio("corrections_mean"),
                      "ratio_iterations": ratio("iterations_mean"),
                      "calibrated_gain": with_["calibrated"] - peer["calibrated"],
                      "clipped_centre_on_shifted_spots": estimator}))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
