"""``heliocal demo``: the full nightly calibration of the embedded simulated plant.

Starts the simulated plant (firmware on ptys and Modbus TCP, simulated double-CCD camera),
builds the error library, runs the campaign through the real drivers, writes the SQLite
database and the morning report into ``--out`` and prints a summary. Rerunning with the
same ``--out`` and seed resumes an interrupted campaign. See docs/campaigns.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from controller.commands._common import add_config_option, add_json_option, print_json
from controller.config import LampSource, PlantConfig, load_config
from controller.errors import InputError
from controller.geometry.vectors import unit, vector_to_azel


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="nightly calibration run of the embedded simulated plant",
                              description=__doc__.splitlines()[0])
    add_config_option(p)
    p.add_argument("--heliostats", type=int, default=12, metavar="N",
                   help="calibrate N heliostats, taken round-robin over the links (default 12)")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="seed of the hidden errors and noise (default: simulation.seed)")
    p.add_argument("--out", default="demo-out", metavar="DIR",
                   help="run directory: database, report, images, ptys (default demo-out/)")
    p.add_argument("--sequential", action="store_true",
                   help="no pipelining: one heliostat after another (for the speedup comparison)")
    p.add_argument("--aim-only", action="store_true",
                   help="only print the aim of each heliostat (source direction, normal, steps)")
    add_json_option(p)
    p.set_defaults(func=run)


def aim_table(cfg: PlantConfig, ids: list[str]) -> list[dict]:
    """Per heliostat: light-source direction, aim normal (bisector), commanded az/el, steps."""
    from controller.geometry.kinematics import HeliostatKinematics

    src = cfg.light_source()
    tgt = np.array(cfg.target().center_enu_m)
    if not isinstance(src, LampSource):
        raise InputError("demo: calibration.light_source must be a lamp (nightly campaign)")
    rows = []
    for hid in ids:
        h = cfg.heliostat(hid)
        pos = np.array(h.position_enu_m)
        s = unit(np.array(src.position_enu_m) - pos)
        normal = unit(s + unit(tgt - pos))
        az, el = vector_to_azel(normal)
        a, e = HeliostatKinematics.from_config(h).steps_for_normal(normal)
        rows.append({"heliostat": hid, "source_dir": s.round(6).tolist(), "normal": normal.round(6).tolist(),
                     "az_deg": round(float(az), 4), "el_deg": round(float(el), 4),
                     "az_steps": int(a), "el_steps": int(e)})
    return rows


def _print_aim(rows: list[dict]) -> None:
    print(f"{'id':5} {'source dir (ENU)':>28} {'aim normal (ENU)':>28} {'az deg':>9} {'el deg':>8}"
          f" {'az steps':>9} {'el steps':>9}")
    for r in rows:
        s = " ".join(f"{c:8.4f}" for c in r["source_dir"])
        m = " ".join(f"{c:8.4f}" for c in r["normal"])
        print(f"{r['heliostat']:5} {s:>28} {m:>28} {r['az_deg']:9.3f} {r['el_deg']:8.3f}"
              f" {r['az_steps']:>9} {r['el_steps']:>9}")


def build_library(cfg: PlantConfig, config_path: str, out: Path, ids: list[str], seed: int, quiet: bool):
    """The error library of the demo: the error set's cases rendered through the plant's own
    camera for three reference heliostats across the field (first, middle, last of the run),
    built once into ``out/library.yaml`` and then reused."""
    from controller.calibration.library import build_library as build
    from controller.calibration.library import load_library, save_library
    from controller.sim.plant import load_config_data, write_reference_set

    path = out / "library.yaml"
    if path.is_file():
        return load_library(path)
    refs = list(dict.fromkeys([ids[0], ids[len(ids) // 2], ids[-1]]))
    if not quiet:
        print(f"building the error library: 6 error-set cases x {len(refs)} reference heliostats ...",
              file=sys.stderr)
    manifest = write_reference_set(load_config_data(config_path), out / "errorset", refs, seed=seed,
                                   source=str(config_path))
    lib = widen_unknown_for_field(build(manifest, kind="log-hu", threshold=cfg.calibration.threshold))
    save_library(lib, path)
    return lib


FIELD_FACTOR = 1.5


def widen_unknown_for_field(lib, factor: float = FIELD_FACTOR):
    """Raise each entry's ``unknown`` threshold to ``factor`` x the largest distance to the
    same case's entries from the other reference heliostats.

    The library's own calibration covers framing and noise of one view; across a field the
    same error looks different from every heliostat (distance, incidence angle), and the
    references measure exactly that spread. Thresholds are only ever raised."""
    x = lib.matrix() / lib.scale
    labels = np.array(lib.labels)
    for i, e in enumerate(lib.entries):
        same = (labels == e.label) & (np.arange(len(labels)) != i)
        if same.any():
            spread = float(np.max(np.linalg.norm(x[same] - x[i], axis=1)))
            e.unknown_distance = max(float(e.unknown_distance), factor * spread)
    return lib


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    if args.heliostats < 1:
        raise InputError(f"--heliostats must be at least 1, got {args.heliostats}")
    from controller.sim.plant import field_selection

    ids = field_selection(cfg, args.heliostats)
    if args.aim_only:
        rows = aim_table(cfg, ids)
        print_json({"heliostats": rows}) if args.json else _print_aim(rows)
        return 0
    return run_campaign(cfg, args, ids)


def run_campaign(cfg: PlantConfig, args: argparse.Namespace, ids: list[str]) -> int:
    seed = cfg.simulation.seed if args.seed is None else args.seed
    out = Path(args.out)
    name = f"demo-n{len(ids)}-seed{seed}" + ("-sequential" if args.sequential else "")
    quiet = args.json or not sys.stderr.isatty()
    summary, result, safety = run_simulated(cfg, args.config, out, out / "campaign.db", ids, seed, name,
                                            sequential=args.sequential, quiet=quiet,
                                            library_dir=out)
    if args.json:
        print_json(summary)
    else:
        _print_summary(summary, result, cfg.simulation.clock_speedup, safety)
    return 0 if result.halted is None else 1


def run_simulated(cfg: PlantConfig, config_path: str, out: Path, db_path: Path, ids: list[str], seed: int,
                  name: str, *, sequential: bool = False, quiet: bool = True,
                  library_dir: Path | None = None) -> tuple[dict, object, dict]:
    """Start the simulated plant in ``out``, run (or resume) campaign ``name`` into ``db_path``
    through the real drivers, write the morning report; return (summary, result, beam safety)."""
    from controller.calibration.campaign import Campaign, CampaignOptions, SimulationHooks, summarize
    from controller.devices.factory import LinkPool
    from controller.reports.campaign import write_report
    from controller.sim.plant import SimulatedPlant, load_config_data
    from controller.storage.db import CampaignStore

    out.mkdir(parents=True, exist_ok=True)
    lib = build_library(cfg, config_path, library_dir or out, ids, seed, quiet)
    store = CampaignStore(db_path)
    try:
        # The plant timeline continues where the recorded work ended, so a resumed campaign's
        # plant-time span covers exactly the recorded work.
        start = store.last_end_s(name) or 0.0
        plant = SimulatedPlant(load_config_data(config_path), out / "plant", heliostat_ids=ids, seed=seed,
                               source=str(config_path), clock_start=start)
        with plant:
            plant_cfg = plant.start()
            cal = cfg.calibration
            opts = CampaignOptions(name=name, pipeline_depth=1 if sequential else cal.pipeline_depth,
                                   settle_s=cal.settle_s, progress=not quiet, image_dir=out / "images")
            with LinkPool(timeout_s=0.5, retries=2) as pool:
                camp = Campaign(plant_cfg, config_path, store, pool, plant.camera, heliostat_ids=ids,
                                library=lib, options=opts, clock=plant.clock, sleep=plant.clock.sleep,
                                hooks=SimulationHooks(plant.true_error_mrad, plant.truth_label),
                                simulated=True, compute=plant.clock.realtime,
                                meta={"seed": seed, "clock_speedup": cfg.simulation.clock_speedup})
                result = camp.run()
            safety = plant.safety.report()
        store.update_meta(result.campaign_id, {"beam_safety_last_session": safety,
                                               "clock_speedup": cfg.simulation.clock_speedup})
        report = write_report(store, out / "report", result.campaign_id)
        summary = summarize(store, result.campaign_id, truth=True)
    finally:
        store.close()
    summary["db"] = str(db_path)
    summary["report"] = str(report)
    return summary, result, safety


def _print_summary(s: dict, result, speedup: float, safety: dict | None = None) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    t = Table(title=f"campaign {result.name}" + (" (resumed)" if result.resumed else ""))
    failures = any(r["fault_cause"] for r in result.runs)
    for col in ("id", "status", "matched case (✓ = truth)", "it", "mrad before", "after", "target s") + (
            ("fault",) if failures else ()):
        t.add_column(col, no_wrap=col not in ("fault", "matched case (✓ = truth)"))
    for r in result.runs:
        occ = (r["off_target_s"] - r["on_target_s"]) if r["off_target_s"] and r["on_target_s"] else None
        m = r["matched_label"] or "unknown"
        case = f"{m} ✓" if m == r["truth_label"] else f"{m} ✗ {r['truth_label']}"
        row = [r["heliostat_id"], r["status"], case,
               str(r["iterations"]), _f(r["true_error_before_mrad"], 2), _f(r["true_error_after_mrad"], 2),
               _f(occ, 1)]
        t.add_row(*row, *([r["fault_cause"] or ""] if failures else []))
    con.print(t)
    con.print(f"simulated plant clock: {speedup:g}x real time; errors are true reflected-beam errors "
              "of the simulated plant")
    con.print(f"calibrated {s['calibrated']}/{s['heliostats']}, failed {s['failed']}; error before "
              f"mean {_f(s['error_before_mrad']['mean'])} max {_f(s['error_before_mrad']['max'])} mrad, "
              f"after mean {_f(s['error_after_mrad']['mean'])} max {_f(s['error_after_mrad']['max'])} mrad")
    con.print(f"{_f(s['heliostats_per_hour'], 0)} heliostats/hour/target (plant time), mean target "
              f"occupancy {_f(s['target_occupancy_s_mean'], 1)} s, pipelined speedup "
              f"{_f(s['pipelined_speedup'], 2)}x")
    con.print(f"database {s['db']}, report {s['report']}")
    if safety is not None:
        con.print(f"beam safety (plant truth): {safety['violations']} of {safety['samples']} samples "
                  f"with two beams on the target; at most {safety['max_beams_on_target']} beam(s) on it")


def _f(v, nd: int = 3) -> str:
    return "-" if v is None else f"{v:.{nd}f}"
