"""The tracking model on real heliostats: 16 Jülich heliostats of PAINT (tests/data/real/paint-field).

    python benchmarks/bench_real_model.py [--json]

Each heliostat's last 10 records are predicted from earlier ones, through the commands' contracts
(``heliocal model fit … --timestamps``, ``model predict --record R… --timestamps --json``,
``model prior``), as an outside script would:

* ``recent20``: fitted to the 20 records just before the last 10;
* ``recent5_prior``: the 5 just before, with a field prior (``model prior``) learned from the
  *other* heliostats' models (each fitted to all its records): the heliostat's own records never
  reach its prior;
* ``first20``: the heliostat's first 20 records (months to years earlier).

The error of a record is the angle between the mirror normal its predicted focal spot implies and
the one its measured UTIS spot implies, both from the heliostat's surveyed position; per heliostat
the median, over the field the median of the heliostats' medians. The peer is a rigid rotation of
the nominal normals fitted to the same records (Kabsch; ``controller.geometry.model.validation``); the
floor the UTIS–HeliOS disagreement on the same records. Heliostats with at least 30 records (the
rule of the held-out check) make ``field``; ``halves`` splits them in two fixed halves, to show
the figure is not one lucky half.

``choices`` shows what each choice of the model buys, in process on the same protocols: the
documented prior of before (rotations' σ 3/15/5 mrad), the prior widened to real heliostats, the
references' random walk in time, and the field prior.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.geometry.aiming import aim_normal, angle_mrad  # noqa: E402
from controller.geometry.frames import wgs84_to_enu  # noqa: E402
from controller.geometry.model.drift import PAINT_JUMP_RAD, RandomWalk  # noqa: E402
from controller.geometry.model.tracking import NAMES, PRIOR_SIGMA_SI, TrackingModel  # noqa: E402
from controller.geometry.model.validation import Targets, held_out  # noqa: E402
from controller.geometry.paint_io import read_paint_set, read_timestamps, read_towers  # noqa: E402

FIELD = ROOT / "tests" / "data" / "real" / "paint-field"
TOWERS = FIELD / "tower-measurements.json"
STAMPS = FIELD / "timestamps.json"
HALVES = (("BE61", "BG54", "BH35", "BH49"), ("BF56", "BG23", "BH36", "BH58"))
BEFORE = {"tilt_east": 3.0, "base_yaw": 15.0, "mirror_offset": 5.0}  # the rotations' σ before, mrad
HELIOCAL = [str(Path(sys.executable).parent / "heliocal")]


def heliostats() -> list[str]:
    return sorted(p.name for p in FIELD.iterdir() if p.is_dir())


def records(h: str, timed: dict) -> list[Path]:
    paths = sorted((FIELD / h / "calibration").glob("*.json"), key=lambda p: int(p.name.split("_")[0]))
    return [p for p in paths if f"{h}_{p.name.split('_')[0]}" in timed]


def cli(*args) -> subprocess.CompletedProcess:
    r = subprocess.run([*HELIOCAL, *map(str, args)], capture_output=True, text=True)
    if r.returncode not in (0,):
        raise SystemExit(f"heliocal {' '.join(map(str, args[:2]))}: exit {r.returncode}: "
                         f"{r.stderr.strip()[-300:]}")
    return r


def spot_error(h: str, record: Path, spot_wgs84, towers) -> float:
    d = json.loads(record.read_text())
    pos = wgs84_to_enu(*json.loads((FIELD / h / f"{h}_properties.json").read_text())["heliostat_position"],
                       *towers.origin_wgs84)
    az, el = math.radians(180.0 - d["sun_azimuth"]), math.radians(d["sun_elevation"])
    sun = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    measured = wgs84_to_enu(*d["focal_spot"]["UTIS"], *towers.origin_wgs84)
    predicted = wgs84_to_enu(*spot_wgs84, *towers.origin_wgs84)
    return float(angle_mrad(aim_normal(sun, pos, predicted), aim_normal(sun, pos, measured)))


def via_cli(h: str, train: list[Path], test: list[Path], tmp: Path, towers, prior: Path | None) -> float:
    """Median error of ``test`` predicted by a model ``model fit`` fitted to ``train``."""
    model = tmp / f"{h}.json"
    cli("model", "fit", *train, "--heliostat-properties", FIELD / h / f"{h}_properties.json",
        "--towers", TOWERS, "--out", model, "--timestamps", STAMPS, *(["--prior", prior] if prior else []))
    out = cli("model", "predict", model, "--record", *test, "--towers", TOWERS, "--timestamps", STAMPS,
              "--json")
    spots = [json.loads(line)["focal_spot_wgs84"] for line in out.stdout.splitlines()]
    return float(np.median([spot_error(h, r, s, towers) for r, s in zip(test, spots, strict=True)]))


def peer_and_floor(h: str, train: list[Path], test: list[Path], timed: dict) -> tuple[float, float]:
    """(median error of the rigid rotation, median UTIS–HeliOS disagreement) on ``test``."""
    ps = read_paint_set([*map(str, train), *map(str, test)], FIELD / h / f"{h}_properties.json", TOWERS,
                        methods=("UTIS", "HeliOS"))
    recs = ps.records
    tr, te = recs[:len(train)], recs[len(train):]
    res = held_out(ps.kinematics, [r.sample for r in tr], [r.sample for r in te],
                   Targets(np.array([r.target.center_enu for r in te]),
                           np.array([r.target.normal for r in te])),
                   noise_mrad=0.8)
    pos = ps.kinematics.position
    floor = [angle_mrad(aim_normal(r.sample.source_dir, pos, r.focal_spots["UTIS"]),
                        aim_normal(r.sample.source_dir, pos, r.focal_spots["HeliOS"]))
             for r in te if {"UTIS", "HeliOS"} <= set(r.focal_spots)]
    return float(np.nanmedian(res.rotation_mrad)), float(np.median(floor)) if floor else float("nan")


def protocols(recs: list[Path]) -> dict[str, list[Path]]:
    before = recs[:-10]
    return {"recent20": before[-20:], "recent5_prior": before[-5:], "first20": before[:20]}


def summary(rows: dict[str, dict], names) -> dict:
    """Median of the medians over ``names`` for every column of ``rows``."""
    cols = {k for r in rows.values() for k in r}
    return {k: float(np.median([rows[h][k] for h in names if h in rows])) for k in sorted(cols)}


def choices(hs: list[str], timed: dict, stamps: dict, field_prior: dict) -> dict:
    """Median of medians per protocol for each model choice (in process, module docstring)."""
    before = PRIOR_SIGMA_SI.copy()
    for n, v in BEFORE.items():
        before[NAMES.index(n)] = v * 1e-3
    walk = RandomWalk(0.1e-3, PAINT_JUMP_RAD)
    variants = {"prior_of_before": dict(prior_sigma=before), "prior_widened": {},
                "widened_and_drift": dict(drift=walk), "drift_and_field_prior": dict(drift=walk, field=True)}
    out = {}
    for name, opts in variants.items():
        per = {p: [] for p in ("recent20", "recent5", "first20")}
        for h in hs:
            recs = records(h, timed)
            ps = read_paint_set([str(p) for p in recs], FIELD / h / f"{h}_properties.json", TOWERS,
                                timestamps=stamps, methods=("UTIS", "HeliOS"))
            samples = ps.records
            sets = {"recent20": (samples[-30:-10], samples[-10:]),
                    "recent5": (samples[-15:-10], samples[-10:]), "first20": (samples[:20], samples[-10:])}
            kw = {k: v for k, v in opts.items() if k != "field"}
            if opts.get("field"):
                fp = field_prior[h]
                kw.update(prior=TrackingModel(fp.mean), prior_sigma=fp.sigma)
            for p, (tr, te) in sets.items():
                res = held_out(ps.kinematics, [r.sample for r in tr], [r.sample for r in te],
                               Targets(np.array([r.target.center_enu for r in te]),
                                       np.array([r.target.normal for r in te])), noise_mrad=0.8, **kw)
                per[p].append(float(np.nanmedian(res.model_mrad)))
        out[name] = {p: float(np.median(v)) for p, v in per.items()}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.parse_args()
    t0 = time.perf_counter()
    towers = read_towers(TOWERS)
    timed = json.loads(STAMPS.read_text())
    stamps = read_timestamps(STAMPS)
    hs = heliostats()
    big = [h for h in hs if len(records(h, timed)) >= 30]
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        models = {}
        for h in hs:
            models[h] = tmp / f"all-{h}.json"
            cli("model", "fit", *records(h, timed), "--heliostat-properties",
                FIELD / h / f"{h}_properties.json", "--towers", TOWERS, "--out", models[h],
                "--timestamps", STAMPS)
        from controller.geometry.model.field_prior_io import read_prior

        field_prior = {}
        for h in big:
            prior = tmp / f"prior-without-{h}.json"
            cli("model", "prior", *[models[g] for g in hs if g != h], "--out", prior)
            field_prior[h] = read_prior(prior)
            recs = records(h, timed)
            test = recs[-10:]
            row = {}
            for name, train in protocols(recs).items():
                row[name] = via_cli(h, train, test, tmp, towers, prior if name == "recent5_prior" else None)
                row[f"{name}_rotation"], row[f"{name}_floor"] = peer_and_floor(h, train, test, timed)
            rows[h] = row
            print(f"  {h}: " + ", ".join(f"{k} {v:.2f}" for k, v in row.items() if "_" not in k or
                                         k == "recent5_prior"), file=sys.stderr)
    field = summary(rows, big)
    for p in ("recent20", "recent5_prior", "first20"):
        field[f"{p}_over_rotation"] = field[p] / field[f"{p}_rotation"]
    out = {"heliostats": len(big), "field": field,
           "halves": [{"heliostats": list(half), **summary(rows, half)} for half in HALVES],
           "per_heliostat": rows, "choices": choices(big, timed, stamps, field_prior),
           "wall_s": time.perf_counter() - t0}
    if "--json" in sys.argv:
        print(json.dumps(out))
    else:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
