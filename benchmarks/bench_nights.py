"""The product's nights as a plant engineer runs them, scored against the simulated plant's truth.

Runs ``heliocal campaign run --simulate`` and then ``--nights`` times ``heliocal campaign night
--simulate`` on a fresh database, each its own process (the simulated plant's night index is
the database's count of nights, so the field drifts between them), and scores the field's
open-loop daytime tracking after the last night **independently**: each heliostat is asked
for its steps at the sun positions of the site's yearly path through the ``heliocal aim``
contract only (its command-line entry point, in this process), and the reflected beam is
traced about ``SimulatedPlant.true_normal_at`` from ``SimulatedPlant.true_mirror_center``
(the plant's truth of that night) to the target centre.

    python benchmarks/bench_nights.py [--nights 3] [--seed 0] [--heliostats IDS] [--every 1]

Prints JSON: per night the command's own summary (measured / planned, status, predicted and
true daytime RMS), then ``independent`` (RMS, p95, max in mrad over heliostats × sun
positions) and the wall time of each process.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller.calibration.night.daytime import sun_path  # noqa: E402
from controller.cli import main as cli  # noqa: E402
from controller.config import load_config  # noqa: E402
from simplant.daytime import true_errors_mrad  # noqa: E402
from simplant.plant import SimulatedPlant, load_config_data  # noqa: E402
from simplant.settings import SimulationSettings  # noqa: E402


def heliocal(*args: str) -> tuple[dict, float]:
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "controller.cli", *args, "--json"], cwd=ROOT,
                       capture_output=True, text=True)
    if p.returncode not in (0, 3):
        sys.exit(f"bench_nights: {' '.join(args[:2])} exited {p.returncode}: {p.stderr.strip()[-400:]}")
    return json.loads(p.stdout), time.perf_counter() - t0


def real_field_config(config: Path, folder: Path) -> Path:
    """The demo configuration with the documented prior (that of real heliostats) in place of
    the demo's narrower σ, in ``folder``: for a field built as the Jülich heliostats are."""
    data = yaml.safe_load(config.read_text())
    model = data["calibration"]["model"]
    model["prior_sigma"] = {k: v for k, v in model.get("prior_sigma", {}).items() if k == "drift_mrad"}
    out = folder / "demo-real-field.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def score(config: Path, db: Path, ids: list[str], night: int, seed: int, every: int, hidden: str) -> dict:
    """Open-loop daytime error (mrad) through ``heliocal aim``, against the plant truth of ``night``."""
    cfg = load_config(config)
    plant = SimulatedPlant(load_config_data(config), db.parent / "score", heliostat_ids=ids,
                           settings=SimulationSettings(seed=seed, hidden_errors=hidden))
    plant.set_night(night)
    target = np.asarray(cfg.target().center_enu_m, float)
    path = sun_path(cfg.site)
    errs = []
    for hid in ids:
        for k in range(0, len(path.times), every):
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                cli(["aim", "--config", str(config), "--db", str(db), "--heliostat", hid,
                     "--sun-az", repr(float(path.azimuth_deg[k])),
                     "--sun-el", repr(float(path.elevation_deg[k])), "--json"])
            out = json.loads(buf.getvalue())
            if "az_steps" not in out:
                continue  # outside the soft limits at this sun position: not tracked then
            steps = [(out["az_steps"], out["el_steps"])]
            errs.append(float(true_errors_mrad(plant, hid, steps, path.directions[k:k + 1], target)[0]))
    e = np.asarray(errs)
    return {"rms": float(np.sqrt(np.mean(e ** 2))), "p95": float(np.percentile(e, 95)), "max": float(e.max()),
            "samples": len(e)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nights", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--heliostats", default=None, help="comma-separated ids (default: all of the demo plant)")
    ap.add_argument("--every", type=int, default=1, help="score every k-th sun position (default 1: all)")
    ap.add_argument("--hidden-errors", choices=("assumed", "paint-field"), default="assumed",
                    help="how the simulated field is built (paint-field: as 16 real Jülich heliostats; the "
                         "demo configuration's narrower prior σ are then dropped: the documented prior is "
                         "that of real heliostats)")
    args = ap.parse_args()
    if not 0 <= args.nights <= 10 or args.every < 1:
        ap.exit(2, "bench_nights.py: --nights must be 0 … 10 and --every at least 1\n")
    config = ROOT / "configs" / "demo.yaml"
    ids = args.heliostats.split(",") if args.heliostats else [h.id for h in load_config(config).heliostats]
    with tempfile.TemporaryDirectory(prefix="bench-nights-") as tmp:
        if args.hidden_errors == "paint-field":
            config = real_field_config(config, Path(tmp))
        db = Path(tmp) / "campaign.db"
        common = ["--config", str(config), "--db", str(db), "--simulate", "--seed", str(args.seed),
                  "--hidden-errors", args.hidden_errors,
                  *(["--heliostats", args.heliostats] if args.heliostats else [])]
        run, wall = heliocal("campaign", "run", *common)
        rows = [{"night": 0, "calibrated": run["calibrated"], "heliostats": run["heliostats"],
                 "status": run["status"], "wall_s": wall}]
        for _ in range(args.nights):
            s, wall = heliocal("campaign", "night", *common)
            rows.append({"night": s["night"], "measured": s["measured"], "planned": s["planned"],
                         "status": s["status"], "predicted_rms": s["daytime_error_predicted_mrad"]["rms"],
                         "true_rms": s["daytime_error_mrad"]["rms"],
                         "true_p95": s["daytime_error_mrad"]["p95"], "wall_s": wall})
        independent = score(config, db, ids, rows[-1]["night"], args.seed, args.every, args.hidden_errors)
    print(json.dumps({"benchmark": "planned nights, separate processes, independent daytime score",
                      "seed": args.seed, "hidden_errors": args.hidden_errors, "heliostats": len(ids),
                      "nights": rows,
                      "independent_daytime_open_loop_mrad": independent}, indent=1))


if __name__ == "__main__":
    main()
