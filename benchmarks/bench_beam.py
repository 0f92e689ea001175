"""Beam analysis and recognition speed (JSON on stdout).

    .venv/bin/python benchmarks/bench_beam.py [--repeat 200]

* ``analyze_hu_match_ms``: :func:`controller.imaging.beam.analyze` (background auto, threshold 0.5,
  Hu moments) + log-Hu features + match against a 6-case library, on a 1024x768 float32 HDR-like
  image with a 140x90 px elliptical spot, noise and a tilted pedestal. Target <= 3 ms.
  ``analyze_none_ms`` is the same with ``background="none"`` (an already dark-subtracted HDR).
  Peer ``cv2_threshold_moments_ms``: a bare OpenCV chain on the full frame (median background,
  5x5 blur, ``minMaxLoc``, ``threshold`` at half the peak, ``moments`` + ``HuMoments``) - no
  plane, no region selection, no d90.
* ``hu_full_frame_ms`` vs ``cv2_hu_full_frame_ms``: Hu moments of the whole float32 frame, ours
  (float64 sums) and ``cv2.HuMoments(cv2.moments(img))`` as the peer.
* ``match_100k_ms``: one query against 100,000 library entries (:class:`Matcher`). Target <= 1 ms.
  Peers: numpy brute force ``norm(X - q)`` and ``cv2.BFMatcher(NORM_L2)`` (float32).

* ``presence_centroid_256_ms`` / ``presence_centroid_1024_ms``: the beam-presence decision and
  the full energy centroid (:func:`controller.imaging.presence.detect_beam` +
  :func:`controller.imaging.spot_centroid.spot_centroid`) on a real 256x256 PAINT photo
  (tests/data/real/paint/106293-cropped.png) and on the 1024x768 image above. Targets <= 5 ms
  and <= 20 ms. Peer in the same run: the default before them,
  ``analyze(img, centroid="segment", presence=False)`` (``old_default_*_ms``), and the whole
  new default ``analyze(img)`` (``analyze_default_*_ms``: presence, centroid and shape);
  ``ratio_*`` = presence + centroid / old default.

Times are medians over ``--repeat`` calls after a warm-up, on this machine's cores.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import cv2
import numpy as np

from controller.imaging.beam import analyze
from controller.imaging.moments import hu_moments
from controller.imaging.presence import detect_beam
from controller.imaging.spot_centroid import spot_centroid
from controller.io.images import read_image
from controller.recognition.library import Entry, Library
from controller.recognition.matching import Matcher


def _median_ms(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def test_image(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:768, 0:1024].astype(np.float32)
    c, s = np.cos(0.4), np.sin(0.4)
    u = ((xx - 530.3) * c + (yy - 370.8) * s) / 70.0
    v = (-(xx - 530.3) * s + (yy - 370.8) * c) / 45.0
    spot = 20000.0 / (1.0 + np.exp(8.0 * (np.hypot(u, v) - 1.0)))
    pedestal = 40.0 + 0.01 * xx + 0.02 * yy
    return (spot + pedestal + rng.normal(0, 15.0, spot.shape)).astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    img = test_image()
    rng = np.random.default_rng(1)

    lib6 = Library("log-hu", 0.5, [Entry(f"case{i}", f) for i, f in enumerate(rng.normal(size=(6, 7)))])

    def pipeline():
        return lib6.match_image(img)

    def pipeline_no_background():
        return lib6.match_hu(analyze(img, threshold=0.5, background="none").hu)

    def cv2_chain():
        sub = img - np.float32(np.median(img[::16, ::16]))
        _, peak, _, _ = cv2.minMaxLoc(cv2.GaussianBlur(sub, (5, 5), 1.0))
        _, spot = cv2.threshold(sub, 0.5 * peak, 0, cv2.THRESH_TOZERO)
        return cv2.HuMoments(cv2.moments(spot))

    big = rng.normal(size=(100_000, 7))
    labels = [f"case{i % 60}" for i in range(100_000)]
    m = Matcher(big, labels)
    queries = rng.normal(size=(args.repeat + 1, 7))
    qi = iter(range(10**9))
    big32 = big.astype(np.float32)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    q32 = queries[:1].astype(np.float32)
    img64 = img.astype(np.float64)
    photo = read_image(Path(__file__).resolve().parents[1] / "tests/data/real/paint/106293-cropped.png")

    def presence_centroid(frame):
        return lambda: spot_centroid(frame, detect_beam(frame))

    def old_default(frame):
        return lambda: analyze(frame, centroid="segment", presence=False)

    speed = {}
    for name, frame in (("256", photo), ("1024", img)):
        new = _median_ms(presence_centroid(frame), args.repeat)
        old = _median_ms(old_default(frame), args.repeat)
        speed[f"presence_centroid_{name}_ms"] = new
        speed[f"old_default_{name}_ms"] = old
        speed[f"analyze_default_{name}_ms"] = _median_ms(lambda f=frame: analyze(f), args.repeat)
        speed[f"ratio_{name}"] = new / old

    result = {
        **speed,
        "image": [768, 1024],
        "cores": os.cpu_count(),
        "analyze_hu_match_ms": _median_ms(pipeline, args.repeat),
        "analyze_none_ms": _median_ms(pipeline_no_background, args.repeat),
        "cv2_threshold_moments_ms": _median_ms(cv2_chain, args.repeat),
        "hu_full_frame_ms": _median_ms(lambda: hu_moments(img), args.repeat),
        "cv2_hu_full_frame_ms": _median_ms(lambda: cv2.HuMoments(cv2.moments(img)), args.repeat),
        "cv2_hu_full_frame_float64_ms": _median_ms(lambda: cv2.HuMoments(cv2.moments(img64)), args.repeat),
        "match_100k_ms": _median_ms(lambda: m.match(queries[next(qi) % len(queries)]), args.repeat),
        "numpy_bruteforce_100k_ms": _median_ms(
            lambda: int(np.argmin(np.linalg.norm(big - queries[0], axis=1))), args.repeat),
        "cv2_bfmatcher_100k_ms": _median_ms(lambda: bf.knnMatch(q32, big32, k=2), max(10, args.repeat // 10)),
        "targets_ms": {"analyze_hu_match": 3.0, "match_100k": 1.0, "presence_centroid_256": 5.0,
                       "presence_centroid_1024": 20.0},
    }
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in result.items()}))


if __name__ == "__main__":
    main()
