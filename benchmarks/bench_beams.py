"""Several beams per target at night (``calibration.beams_per_target``): the same planned night
with K = 1 and with K = 4 on the simulated plant with its full camera, scored against the plant's truth.

The field is the demo plant's (``configs/demo.yaml``: 18 heliostats, two targets of
9.3 m × 7 m on the tower, ray-traced double-CCD cameras) with two more rows of six heliostats
staggered into it (``--extra-rows 2``, the default: 30 heliostats, passes of 13–15 on a
target), lit by lamps far from the field (``simplant.far_lamps``, about 300 m): a lamp a few
tens of metres away is imaged far behind the target by a mirror focused at ~50 m and makes a
spot nearly as wide as the mirror (geometry/spot.py, Eq. 1), and the slot layout then fits one
beam per target whatever K says. Far lamps make spots of about a metre, so up to four fit.

Geometries per hour per target is a rate, measured on passes long enough for several full
rounds, as a real field's are (hundreds of heliostats per target). On the demo's own 18
(``--extra-rows 0``) a pass holds 8–9 heliostats: its first slew onto the target and its last
round — one beam, a whole single-beam cycle — are a third of it, and the ratio is lower
(docs/results.md, "Several beams per target").

Steps, each a plant session of its own as separate processes would be:

1. night 0 (K = 1): the calibration campaign at the first lamp; night 1 (K = 1): a planned
   night, so every heliostat has a model at every lamp (slots need the position uncertainty
   of a fitted model);
2. the database is copied twice and **night 2** is run on each copy, once with K = 1 and
   once with K = 4, same seed (same plant drift and noise draws).

Per run (JSON ``k1``, ``k4``): ``planned``, ``measured``; ``geometries_per_hour_per_target``:
measurements over the plant hours the targets were busy (per pass, first beam on the
target to last beam off it, summed over the passes of both targets); ``misassigned``:
measurements whose centroid is another heliostat's spot in the plant's truth
(``simplant.spot_truth``); ``centroid_error_mm``: mean, p95 and max distance of the measured
centroids from the centre of their own spot (the reflected central ray's hit) in the plant's
truth; ``daytime_rms_mrad``: the field's open-loop error over the sun's
yearly path after the night, against the plant's truth (``simplant.daytime``);
``daytime_rms_per_heliostat_mrad``: the same per heliostat;
``measured_alone``: heliostats whose spot could not be confirmed in a shared capture and
were measured again alone; ``beam_safety_violations``: samples with more beams on a target
than allowed. ``ratio``: K = 4 over K = 1 geometries per hour per target.

    python benchmarks/bench_beams.py [--json] [--seed 0] [--k 4] [--extra-rows 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.commands.field import open_store  # noqa: E402
from controller.commands.simulated import calibrate, planned_night  # noqa: E402
from controller.config import load_config  # noqa: E402
from simplant.far_lamps import FAR_LAMPS, far_lamp_config  # noqa: E402
from simplant.settings import SimulationSettings  # noqa: E402


def bench_config(folder: Path, k: int, rows: int) -> Path:
    """The demo plant under the far lamps, ``calibration.beams_per_target: k``, ``rows`` rows of
    six heliostats staggered into its field (``simplant.far_lamps``)."""
    return far_lamp_config(ROOT / "configs" / "demo.yaml", folder, k, rows)


def busy_hours(db: Path, night: str) -> tuple[float, int, int]:
    """Plant hours the targets were busy during ``night`` (per pass: first beam on to last
    beam off), the number of passes, and the heliostats measured again alone."""
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT MIN(r.on_target_s), MAX(r.off_target_s) FROM heliostat_runs r "
                           "JOIN campaigns c ON c.id = r.campaign_id WHERE c.name LIKE ? "
                           "AND r.on_target_s IS NOT NULL GROUP BY c.id", (f"{night}/%",)).fetchall()
        metas = con.execute("SELECT meta_json FROM campaigns WHERE name LIKE ?", (f"{night}/%",)).fetchall()
    finally:
        con.close()
    alone = sum(len(json.loads(m or "{}").get("beams", {}).get("measured_alone", [])) for (m,) in metas)
    return sum(b - a for a, b in rows if a is not None and b is not None) / 3600.0, len(rows), alone


def centroid_errors(errors_m: list[float]) -> dict:
    """Mean, p95 and max (mm) of the measured centroids' distances from their own spots."""
    e = 1e3 * np.asarray(errors_m, float)
    if not e.size:
        return {}
    return {"mean": float(e.mean()), "p95": float(np.percentile(e, 95)), "max": float(e.max()),
            "n": int(e.size)}


def copy_db(source: Path, dest: Path) -> None:
    """A consistent copy of ``source`` (SQLite's online backup: the write-ahead log included)."""
    src, dst = sqlite3.connect(source), sqlite3.connect(dest)
    try:
        src.backup(dst)
    finally:
        src.close()
        dst.close()


def run_night(config: Path, db: Path, ids: list[str], seed: int) -> dict:
    cfg = load_config(config)
    safety: dict = {}
    store = open_store(db)
    t0 = time.perf_counter()
    try:
        rep = planned_night(cfg, str(config), store, db.parent / "sim", ids, SimulationSettings(seed=seed),
                            "bench", library_dir=db.parent.parent / "library", safety=safety)
    finally:
        store.close()
    hours, passes, alone = busy_hours(db, rep.summary.name)
    return {"planned": rep.planned, "measured": rep.measured, "passes": passes,
            "target_busy_hours": hours,
            "geometries_per_hour_per_target": rep.measured / hours if hours > 0 else 0.0,
            "misassigned": safety.get("misassigned", 0),
            "centroid_error_mm": centroid_errors(safety.get("centroid_errors_m", [])),
            "measured_alone": alone,
            "beam_safety_violations": safety.get("violations", 0),
            "max_beams_on_target": safety.get("max_beams_on_target", 0),
            "daytime_rms_mrad": rep.daytime.rms,
            "daytime_rms_per_heliostat_mrad": {h: round(v, 4)
                                               for h, v in sorted(rep.daytime.per_heliostat.items())},
            "status": rep.summary.status,
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print JSON only")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--k", type=int, default=4, help="beams per target of the second run (2 … 8)")
    ap.add_argument("--extra-rows", type=int, default=2,
                    help="rows of six heliostats staggered into the demo field (0 … 6; default 2: "
                         "30 heliostats); 0: the demo's 18")
    ap.add_argument("--out", type=Path, default=None,
                    help="keep the configurations and databases here (default: a temporary folder)")
    args = ap.parse_args()
    if not 2 <= args.k <= 8:
        ap.exit(2, "bench_beams.py: --k must be 2 … 8\n")
    if not 0 <= args.extra_rows <= 6:
        ap.exit(2, "bench_beams.py: --extra-rows must be 0 … 6\n")
    if args.out is not None and args.out.exists() and any(args.out.iterdir()):
        ap.exit(2, f"bench_beams.py: --out {args.out} is not empty\n")
    with tempfile.TemporaryDirectory(prefix="bench-beams-") as tmp:
        root = args.out or Path(tmp)
        one = bench_config(root / "k1", 1, args.extra_rows)
        many = bench_config(root / f"k{args.k}", args.k, args.extra_rows)
        ids = [h.id for h in load_config(one).heliostats]
        base = root / "prep" / "campaign.db"
        base.parent.mkdir()
        settings = SimulationSettings(seed=args.seed)
        store = open_store(base)
        t0 = time.perf_counter()
        try:
            calibrate(load_config(one), str(one), store, base.parent / "sim", ids, settings, "bench",
                      library_dir=root / "library")
        finally:
            store.close()
        run_night(one, base, ids, args.seed)
        prep_s = time.perf_counter() - t0
        out = {}
        for key, config in (("k1", one), (f"k{args.k}", many)):
            db = config.parent / "campaign.db"
            copy_db(base, db)
            out[key] = run_night(config, db, ids, args.seed)
    k1, kk = out["k1"], out[f"k{args.k}"]
    result = {"benchmark": "several beams per target, the same planned night (night 2) with K = 1 and K = "
                           f"{args.k}, full camera, plant truth", "seed": args.seed, "heliostats": len(ids),
              "lamps": [i for i, _ in FAR_LAMPS], **out,
              "ratio": kk["geometries_per_hour_per_target"] / max(k1["geometries_per_hour_per_target"], 1e-9),
              "daytime_rms_difference_mrad": kk["daytime_rms_mrad"] - k1["daytime_rms_mrad"],
              "prepare_wall_s": prep_s}
    print(json.dumps(result, indent=None if args.json else 1))


if __name__ == "__main__":
    main()
