"""Benchmark of archive reprocessing on Dask: local clusters of N and 1 workers vs a plain loop.

The archive: a demo run of the simulated plant (3 heliostats, the calibration night and one
planned night, 256×192 cameras to keep the run short) repeated over as many nights as it takes to
reach --pairs frame pairs (simplant.archive.replicate; frames hard-linked, so they come from the
page cache: this measures the analysis and the orchestration, not the disk). The same work three
ways, each writing its own output database through the same single writer:

* ``loop`` (the peer): a plain loop in this process over the same pairs and refits (no Dask);
* ``dask_1`` / ``dask_N``: ``reprocess()`` on a local cluster of 1 / ``--workers`` worker
  processes (cluster start-up timed apart), its tasks sized to ~0.3 s from the measured cost.

``per_worker_efficiency`` = cluster pairs/s / (workers × loop pairs/s): 1 when every worker
does the loop's work with no overhead. Each way's CPU seconds (this process, and the workers'
own) are reported beside its wall time, and the load average: on a machine shared with other
jobs the wall-time ratios measure the sharing as much as Dask. The per-pair cost at the demo's
full 1024×768 (a short run on the demo archive itself) gives the projection for a year of a
10,000-heliostat field, stated as arithmetic, not measured.

Usage: .venv/bin/python benchmarks/bench_reprocess.py [--pairs 5000] [--workers 2] [--json] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from controller.calibration.reprocess.plan import (
    MAX_TASK_PAIRS,
    in_scope,
    load_configs,
    plan_pairs,
    refit_specs,
    take_task,
)
from controller.calibration.reprocess.run import open_cluster, reprocess
from controller.calibration.reprocess.tasks import analyse_chunk, refit
from controller.commands.simulated import plant_crf_config
from controller.storage.db import open_existing
from controller.storage.reprocess.archive import fingerprint, read_archive
from controller.storage.reprocess.db import open_output
from simplant.archive import replicate

NIGHT_PAIRS = 30_000  # a 10,000-heliostat field, three measurements each (the figure)
YEAR_PAIRS = 365 * NIGHT_PAIRS  # a year of nights of that field
PROJECTED_WORKERS = (16, 64, 256)


def cpu_s() -> float:
    """CPU seconds of this process so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def workers_cpu_s(client) -> float:
    """CPU seconds of every worker process of ``client``'s cluster so far."""
    return sum(client.run(cpu_s).values())


def tasks(planned) -> list:
    """The pairs of ``planned`` as the loop runs them: one chunk per campaign's run of pairs
    (a loop pays no per-task cost)."""
    it, out = iter(planned), []
    while task := take_task(it, MAX_TASK_PAIRS):
        out.extend(task)
    return out


def demo(work: Path, small: bool) -> Path:
    """Record a demo run whose configuration holds the plant's camera responses."""
    config = plant_crf_config(work, small=small)
    r = subprocess.run([sys.executable, "-m", "controller.cli", "demo", "--config", str(config),
                        "--heliostats", "3", "--nights", "1", "--out", str(work / "demo"), "--json"],
                       capture_output=True, text=True)
    if r.returncode not in (0, 3):  # 3: a night ended partial, its archive is still the archive to reprocess
        raise SystemExit(f"bench_reprocess: heliocal demo exited {r.returncode}: {r.stderr.strip()[-400:]}")
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


def peer(o: _Output) -> tuple[float, float, float]:
    """(pairs s, pairs CPU s, refits s) of the same work in a plain loop: every pair, then every
    refit, written by the same writer."""
    src, out = o.open("peer")
    try:
        t0, c0 = time.perf_counter(), cpu_s()
        old = {m.id: m for m in o.archive.measurements}
        for spec, pairs in tasks(plan_pairs(o.archive, o.configs, o.scope, None)):
            out.record_pairs(analyse_chunk(spec, pairs), old)
        t1, c1 = time.perf_counter(), cpu_s()
        out.record_models([refit(s) for s in refit_specs(o.archive, o.configs, out.pair_results())],
                          o.archive.models)
        return t1 - t0, c1 - c0, time.perf_counter() - t1
    finally:
        out.close()
        src.close()


def dask(o: _Output, workers: int) -> dict:
    """Start-up s, pairs s, the pairs' CPU s (this process; the workers'), refits s of
    ``reprocess()`` on a local cluster of ``workers`` processes (the phases split where its
    progress reports the first refit)."""
    src, out = o.open(f"dask{workers}")
    marks: dict[str, float] = {}

    def progress(phase: str, done: int, total: int) -> None:
        if phase not in marks:
            marks[phase] = time.perf_counter()
            marks[f"{phase}_cpu"] = cpu_s()
            marks[f"{phase}_workers_cpu"] = workers_cpu_s(cluster.client)

    try:
        t0 = time.perf_counter()
        with open_cluster(None, workers) as cluster:
            t1 = time.perf_counter()
            reprocess(cluster, o.archive, o.configs, o.scope, out, images_dir=None, progress=progress)
            t2 = time.perf_counter()
        return {"startup_s": t1 - t0, "pairs_s": marks["refits"] - marks["pairs"],
                "pairs_client_cpu_s": marks["refits_cpu"] - marks["pairs_cpu"],
                "pairs_workers_cpu_s": marks["refits_workers_cpu"] - marks["pairs_workers_cpu"],
                "refits_s": t2 - marks["refits"]}
    finally:
        out.close()
        src.close()


def per_pair_full_size(work: Path) -> float:
    """Seconds per pair at 1024×768 in one process (warm chain), on the full-size demo archive."""
    db = demo(work, small=False)
    with open_existing(db) as src:
        a = read_archive(src)
    c = load_configs(a)
    work_chunks = tasks(plan_pairs(a, c, in_scope(a, None), None))
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
    ap.add_argument("--workers", type=int, default=2, help="workers of the cluster measured (default 2)")
    ap.add_argument("--json", action="store_true", help="print one JSON object on one line")
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one)")
    args = ap.parse_args()
    if not 1 <= args.pairs <= 10_000_000 or not 1 <= args.workers <= 64:
        ap.exit(2, "bench_reprocess.py: --pairs in [1, 10000000], --workers in [1, 64]\n")
    load0 = os.getloadavg()
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
        t_loop, c_loop, f_loop = peer(o)
        one = dask(o, 1)
        many = dask(o, args.workers)
        full = per_pair_full_size(work / "full")
    loop_rate, one_rate, rate = n / t_loop, n / one["pairs_s"], n / many["pairs_s"]
    eff = rate / (args.workers * loop_rate)
    cpu_eff = c_loop / (many["pairs_client_cpu_s"] + many["pairs_workers_cpu_s"])
    year = {w: YEAR_PAIRS * full / (w * eff) / 3600.0 for w in PROJECTED_WORKERS}
    result = {
        "pairs": n, "camera_px": [256, 192], "heliostats": 3, "cores": os.cpu_count(),
        "load_average": {"start": [round(x, 2) for x in load0],
                         "end": [round(x, 2) for x in os.getloadavg()]},
        "workers": args.workers,
        "loop_pairs_per_s": round(loop_rate, 1), "cluster_pairs_per_s": round(rate, 1),
        "one_worker_pairs_per_s": round(one_rate, 1),
        "per_worker_efficiency": round(eff, 3),
        "one_worker_efficiency": round(one_rate / loop_rate, 3),
        "cpu_efficiency": round(cpu_eff, 3),
        "pairs_wall_s": {"loop": round(t_loop, 2), "dask_1": round(one["pairs_s"], 2),
                         f"dask_{args.workers}": round(many["pairs_s"], 2)},
        "pairs_cpu_s": {"loop": round(c_loop, 2),
                        "dask_1": {"client": round(one["pairs_client_cpu_s"], 2),
                                   "workers": round(one["pairs_workers_cpu_s"], 2)},
                        f"dask_{args.workers}": {"client": round(many["pairs_client_cpu_s"], 2),
                                                 "workers": round(many["pairs_workers_cpu_s"], 2)}},
        "refits_wall_s": {"loop": round(f_loop, 2), "dask_1": round(one["refits_s"], 2),
                          f"dask_{args.workers}": round(many["refits_s"], 2)},
        "cluster_startup_s": {"dask_1": round(one["startup_s"], 2),
                              f"dask_{args.workers}": round(many["startup_s"], 2)},
        "per_pair_s_1024x768": round(full, 4),
        "projection": {
            "assumes": "per-pair cost at 1024x768 measured here, the per-worker efficiency measured here, "
                       "frames read as fast as they are analysed",
            "night_pairs": NIGHT_PAIRS, "year_pairs": YEAR_PAIRS, "efficiency": round(eff, 3),
            "year_hours": {str(w): round(h, 2) for w, h in year.items()},
            "arithmetic": f"{YEAR_PAIRS} pairs x {full:.4f} s / (W workers x {eff:.3f})",
        },
    }
    print(json.dumps(result, indent=None if args.json else 1))


if __name__ == "__main__":
    main()
