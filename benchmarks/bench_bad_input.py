"""The bounded image reader against hostile files and on valid ones (JSON on stdout).

    .venv/bin/python benchmarks/bench_bad_input.py [--repeat 20]

* ``refuse``: per file of the bad-input corpus (tests/io/badfiles.py), the median time in ms
  :func:`controller.io.images.read_image` takes to refuse it and the peak of Python-traced
  allocations (tracemalloc; numpy's included) in MB during the refusal. Target: every file
  refused in < 50 ms with < 2 × its size allocated.
* ``bomb_unbounded``: the peer, ``cv2.imdecode`` of the same bomb PNG without the header check:
  time and the bytes of the array it builds.
* ``valid_5mpx_ms``: a valid 2448×2048 16-bit PNG read by ``read_image`` (header check, then
  ``cv2.imdecode``) against a bare ``cv2.imread``: the cost of the checks on a real frame.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "io"))  # the corpus generator

from badfiles import corpus  # noqa: E402

from controller.errors import InputError  # noqa: E402
from controller.io.images import read_image  # noqa: E402

VALID_IMAGES = {"png_named.yaml", "png_named.json", "png_named.csv"}  # PNGs under other names


def _refuse(path: Path, repeat: int) -> dict:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        try:
            read_image(path)
        except InputError:
            pass
        else:
            raise AssertionError(f"{path.name} was accepted")
        times.append((time.perf_counter() - t0) * 1e3)
    tracemalloc.start()
    try:
        read_image(path)
    except InputError:
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"bytes": path.stat().st_size, "ms": round(statistics.median(times), 3),
            "peak_mb": round(peak / 1e6, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20, help="timed calls per file (median)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        files = {}
        for name, data in corpus().items():
            (folder / name).write_bytes(data)
            files[name] = folder / name
        refuse = {name: _refuse(p, args.repeat) for name, p in files.items() if name not in VALID_IMAGES}
        bomb = files["bomb.png"].read_bytes()
        t0 = time.perf_counter()
        img = cv2.imdecode(np.frombuffer(bomb, np.uint8), cv2.IMREAD_UNCHANGED)
        unbounded = {"ms": round((time.perf_counter() - t0) * 1e3, 1),
                     "decoded_bytes": None if img is None else int(img.nbytes)}
        del img
        frame = np.random.default_rng(0).integers(0, 4096, (2048, 2448), dtype=np.uint16)
        cv2.imwrite(str(folder / "frame.png"), frame)
        assert np.array_equal(read_image(folder / "frame.png"), frame)
        reps = max(3, args.repeat // 4)
        t_ours, t_cv2 = [], []
        for _ in range(reps):
            t0 = time.perf_counter()
            read_image(folder / "frame.png")
            t_ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            cv2.imread(str(folder / "frame.png"), cv2.IMREAD_UNCHANGED)
            t_cv2.append(time.perf_counter() - t0)
    print(json.dumps({
        "refuse": refuse,
        "max_refuse_ms": max(r["ms"] for r in refuse.values()),
        "max_peak_mb": max(r["peak_mb"] for r in refuse.values()),
        "bomb_unbounded": unbounded,
        "valid_5mpx_ms": {"read_image": round(statistics.median(t_ours) * 1e3, 1),
                          "cv2_imread": round(statistics.median(t_cv2) * 1e3, 1)},
    }))


if __name__ == "__main__":
    main()
