"""Benchmark of archive reprocessing on Dask: 1 worker vs 2 workers vs a plain single-process loop.

The archive: a demo run of the simulated plant (3 heliostats, the calibration night and one
planned night, 256×192 cameras to keep the run short) repeated over as many nights as it takes to
reach --pairs frame pairs (simplant.archive.replicate; frames hard-linked, so they come from the
page cache: this measures the analysis and the orchestration, not the disk). The same work three
ways, each writing its own output database through the same single writer:

* ``peer``: a plain loop in this process over the same chunks and refits (no Dask);
* ``dask_1`` / ``dask_2``: ``reprocess()`` on a local cluster of 1 / 2 worker processes (cluster
  start-up timed apart).

Prints one JSON object: pairs, pairs/s of each (the pair phase; the 3 refits timed apart), the
ratios (dask_1/peer: the orchestration's overhead; dask_2/dask_1: the scaling on this machine's
2 cores), the per-pair cost at the demo's full 1024×768 (a short run on the demo archive
itself), and a cluster projection stated as arithmetic from those measurements, not measured.

Usage: .venv/bin/python benchmarks/bench_reprocess.py [--pairs 5000] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from controller.calibration.reprocess import analyse_chunk, refit_heliostat
from controller.calibration.reprocess_plan import chunks, in_scope, load_configs, plan_pairs, refit_specs
from controller.calibration.reprocess_run import open_cluster, reprocess
from controller.commands._common import PACKAGED_CONFIG
from controller.storage.archive import fingerprint, read_archive
from controller.storage.db import open_existing
from controller.storage.reprocess_db import open_output
from simplant.archive import replicate

NIGHT_PAIRS = 30_000  # a 10,000-heliostat field, three measurements each (the figure)


def demo(work: Path, small: bool) -> Path:
    """Record a demo run whose configuration holds the plant's camera responses."""
    from simplant.plant import SimulatedPlant
    from simplant.settings import SimulationSettings

    data = yaml.safe_load(Path(PACKAGED_CONFIG).read_text())
    if small:
        for cam in [data["camera"]] + [t["camera"] for t in data["targets"] if t.get("camera")]:
            cam["width_px"], cam["height_px"] = 256, 192
            if cam.get("registration"):
                cam["registration"]["focal_px"] *= 256 / 1024
    with SimulatedPlant(data, work / "plant0", settings=SimulationSettings(seed=0)) as plant:
        plant.start()
    data["camera"]["crf_file"] = str(work / "plant0" / "crf.yaml")
    for t in data["targets"]:
        if t.get("camera"):
            t["camera"]["crf_file"] = str(work / "plant0" / f"crf-{t['id']}.yaml")
    config = work / "plant.yaml"
    config.write_text(yaml.safe_dump(data, sort_keys=False))
    subprocess.run([sys.executable, "-m", "controller.cli", "demo", "--config", str(config), "--heliostats",
                    "3", "--nights", "1", "--out", str(work / "demo"), "--json"], check=True,
                   capture_output=True)
    return work / "demo" / "campaign.db"


class _Output:
    """Opens a fresh output database for one way of running."""

    def __init__(self, db: Path, work: Path) -> None:
        self.db, self.work = db, work
        with open_existing(db) as src:
            self.archive = read_archive(src)
        self.configs = load_configs(self.archive)
        self.scope = in_scope(self.archive, None)

    def open(self, name: str):
        src = open_existing(self.db)
        out = open_output(src, self.work / f"{name}.db", fingerprint(self.db),
                          {"since": None, "images": None})
        return src, out


def peer(o: _Output) -> tuple[float, float]:
    """(pairs s, refits s) of the same work in a plain loop: every chunk, then every refit,
    written by the same writer."""
    src, out = o.open("peer")
    try:
        t0 = time.perf_counter()
        old = {m.id: m for m in o.archive.measurements}
        for spec, pairs in chunks(plan_pairs(o.archive, o.configs, o.scope, None), 1):
            out.record_pairs(analyse_chunk(spec, pairs), old)
        t1 = time.perf_counter()
        out.record_models([refit_heliostat(s) for s in refit_specs(o.archive, o.configs, out.pair_results())],
                          o.archive.models)
        return t1 - t0, time.perf_counter() - t1
    finally:
        out.close()
        src.close()


def dask(o: _Output, workers: int) -> tuple[float, float, float]:
    """(start-up s, pairs s, refits s) of ``reprocess()`` on a local cluster of ``workers``
    processes (the phases split where its progress reports the first refit)."""
    src, out = o.open(f"dask{workers}")
    marks: dict[str, float] = {}

    def progress(phase: str, done: int, total: int) -> None:
        marks.setdefault(phase, time.perf_counter())

    try:
        t0 = time.perf_counter()
        with open_cluster(None, workers) as cluster:
            t1 = time.perf_counter()
            reprocess(cluster, o.archive, o.configs, o.scope, out, images_dir=None, progress=progress)
            t2 = time.perf_counter()
        return t1 - t0, marks["refits"] - t1, t2 - marks["refits"]
    finally:
        out.close()
        src.close()


def per_pair_full_size(work: Path) -> float:
    """Seconds per pair at 1024×768 in one process (warm chain), on the full-size demo archive."""
    db = demo(work, small=False)
    with open_existing(db) as src:
        a = read_archive(src)
    c = load_configs(a)
    work_chunks = chunks(plan_pairs(a, c, in_scope(a, None), None), 1)
    for spec, pairs in work_chunks[:1]:
        analyse_chunk(spec, pairs[:1])  # builds the chains (registration maps) once
    n, t0 = 0, time.perf_counter()
    for spec, pairs in work_chunks:
        analyse_chunk(spec, pairs)
        n += len(pairs)
    return (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=5000, help="synthetic archive size (default 5000)")
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        source = demo(work / "small", small=True)
        with open_existing(source) as s:
            per_copy = sum(1 for _ in s.query("SELECT DISTINCT measurement_id FROM images"))
        copies = -(-args.pairs // per_copy)
        # Copies minutes apart: one night for the model's epochs, so the 3 refits stay short and
        # the run measures the pairs (a season's hundreds of epochs per heliostat cost minutes
        # per refit, a cost that parallelises over a field's heliostats, not over 3).
        n = replicate(source, work / "archive.db", work / "images", copies, spacing_h=0.05)
        o = _Output(work / "archive.db", work)
        t_peer, f_peer = peer(o)
        up1, t1, f1 = dask(o, 1)
        up2, t2, f2 = dask(o, 2)
        full = per_pair_full_size(work / "full")
    rate = {"peer": n / t_peer, "dask_1": n / t1, "dask_2": n / t2}
    eff = rate["dask_2"] / (2 * rate["dask_1"])  # per-worker efficiency of 2 workers vs 1
    w = 64
    night_s = NIGHT_PAIRS * full / (w * eff)
    print(json.dumps({
        "pairs": n, "camera_px": [256, 192], "heliostats": 3, "cores": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "pairs_wall_s": {"peer": round(t_peer, 2), "dask_1": round(t1, 2), "dask_2": round(t2, 2)},
        "refits_wall_s": {"peer": round(f_peer, 2), "dask_1": round(f1, 2), "dask_2": round(f2, 2)},
        "cluster_startup_s": {"dask_1": round(up1, 2), "dask_2": round(up2, 2)},
        "pairs_per_s": {k: round(v, 1) for k, v in rate.items()},
        "ratio_dask_1_vs_peer": round(rate["dask_1"] / rate["peer"], 3),
        "ratio_dask_2_vs_dask_1": round(rate["dask_2"] / rate["dask_1"], 3),
        "ratio_dask_2_vs_peer": round(rate["dask_2"] / rate["peer"], 3),
        "per_pair_s_1024x768": round(full, 4),
        "projection": {
            "assumes": "per-pair cost at 1024x768 measured here, the 2-worker efficiency measured here, "
                       "frames read as fast as they are analysed",
            "workers": w, "night_pairs": NIGHT_PAIRS, "efficiency": round(eff, 3),
            "arithmetic": f"{NIGHT_PAIRS} pairs x {full:.4f} s / ({w} workers x {eff:.3f}) = {night_s:.0f} s",
            "night_s": round(night_s, 1),
        },
    }))


if __name__ == "__main__":
    main()
