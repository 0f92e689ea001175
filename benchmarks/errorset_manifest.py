"""The manifest protocol both independent error sets follow (``independent_spots``,
``facet_spots``): per case, a library image at each of ``magnitudes`` and ``views`` test
views with magnitude 0.5–1.5, spot size, rotation, zoom, shift and exposure drawn at random,
written as ``.npy`` images with ``library.csv`` and ``test.csv``
(``image,label,az_deg,el_deg,magnitude,spot``) — the format ``heliocal library build`` and
``heliocal report confusion`` read. Only the protocol is shared; each renderer keeps its own
physics."""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np


def write_manifest_set(out: str | Path, render: Callable, cases: Sequence[str], *, seed: int, views: int,
                       magnitudes, spot_range, stream: int, shift_px: float,
                       exposure_range: tuple[float, float]) -> tuple[Path, Path]:
    """Write the set (module docstring) rendered by ``render(case, magnitude, rng, **view)``;
    ``stream`` keeps each renderer's random streams apart. The two manifests' paths."""
    out = Path(out)
    (out / "images").mkdir(parents=True, exist_ok=True)
    lib_rows, test_rows = [], []
    for ci, case in enumerate(cases):
        for mi, m in enumerate(magnitudes):
            rng = np.random.default_rng([seed, ci, mi, stream])
            name = f"images/lib-{case}-{mi}.npy"
            np.save(out / name, render(case, m, rng))
            lib_rows.append([name, case, "", "", f"{m:.4f}", "1.0"])
        rng = np.random.default_rng([seed, ci, stream + 1])
        for k in range(views):
            m = float(rng.uniform(0.5, 1.5))
            spot = float(np.exp(rng.uniform(np.log(spot_range[0]), np.log(spot_range[1]))))
            rotation = float(rng.uniform(0, 2 * np.pi))
            zoom = float(np.exp(rng.uniform(np.log(0.8), np.log(1.25))))
            shift = (float(rng.uniform(-shift_px, shift_px)), float(rng.uniform(-shift_px, shift_px)))
            exposure = float(np.exp(rng.uniform(*np.log(exposure_range))))
            img = render(case, m, rng, spot=spot, rotation_rad=rotation, zoom=zoom, shift_px=shift,
                         exposure=exposure)
            name = f"images/test-{case}-{k:02d}.npy"
            np.save(out / name, img)
            test_rows.append([name, case, "", "", f"{m:.4f}", f"{spot:.3f}"])
    header = ["image", "label", "az_deg", "el_deg", "magnitude", "spot"]
    for fname, rows in (("library.csv", lib_rows), ("test.csv", test_rows)):
        with open(out / fname, "w", newline="", encoding="utf-8") as f:
            csv.writer(f, lineterminator="\n").writerows([header, *rows])
    return out / "library.csv", out / "test.csv"
