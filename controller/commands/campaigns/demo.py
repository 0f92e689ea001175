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

from controller.commands._numbers import SEED, Number
from controller.commands.campaigns._demo_coarse import (
    centroid_only_twin,
    print_uncalibrated,
    uncalibrated_field,
    uncalibrated_scale,
)
from controller.commands.common import (
    add_config_option,
    add_hidden_errors_option,
    add_json_option,
    output_dir,
    print_json,
)
from controller.config import load_config
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="nightly calibration run of the embedded simulated plant",
                              description=__doc__.splitlines()[0])
    add_config_option(p)
    p.add_argument("--heliostats", type=Number(1, 10000, integer=True), default=12, metavar="N",
                   help="calibrate N heliostats, taken round-robin over the links (default 12)")
    p.add_argument("--seed", type=SEED, default=0, metavar="S",
                   help="seed of the hidden errors and noise (default 0)")
    p.add_argument("--out", default="demo-out", metavar="DIR",
                   help="run directory: database, report, images, ptys (default demo-out/)")
    p.add_argument("--nights", type=Number(0, 100, integer=True), default=3, metavar="N",
                   help="planned nights after the first calibration (several lamps and aim points, "
                        "chosen for the daytime error; default 3, 0: the calibration only)")
    p.add_argument("--sequential", action="store_true",
                   help="no pipelining: one heliostat after another (for the speedup comparison)")
    p.add_argument("--uncalibrated", type=uncalibrated_scale, default=None, metavar="MRAD|real",
                   help="then calibrate the same heliostats on a plant whose hidden errors have this "
                        "scale in (0, 200] mrad (a newly installed field, first spots at the view's edge "
                        "or out of view: the beam search finds them), or 'real': each heliostat off as "
                        "the real Jülich heliostats were before their first calibration; with the coarse "
                        "correction and centroid only (make demo: 12; docs/commissioning.md)")
    add_hidden_errors_option(p)
    p.add_argument("--aim-only", action="store_true",
                   help="only print the aim of each heliostat (source direction, normal, steps)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.calibration.cycle.model_update import model_prior
    from controller.commands.simulated import field_selection

    output_dir(args.out)  # an existing file there is refused before any work
    cfg = load_config(args.config)
    model_prior(cfg.calibration.model, str(args.config))  # refused before any slow work
    if not 1 <= args.heliostats <= len(cfg.heliostats):
        raise InputError(f"--heliostats must be 1 … {len(cfg.heliostats)} (the heliostats of {args.config}), "
                         f"got {args.heliostats}")
    if not 0 <= args.nights <= 30:
        raise InputError(f"--nights must be 0 … 30, got {args.nights}")
    ids = field_selection(cfg, args.heliostats)
    if args.aim_only:
        from controller.geometry.nominal_aim import nominal_aims

        rows = [{"heliostat": a.heliostat_id, "source_dir": a.source_dir.round(6).tolist(),
                 "normal": a.normal.round(6).tolist(), "az_deg": round(a.az_deg, 4),
                 "el_deg": round(a.el_deg, 4), "az_steps": a.az_steps, "el_steps": a.el_steps}
                for a in nominal_aims(cfg, ids)]
        if args.json:
            print_json({"heliostats": rows})
        else:
            _print_aim(rows)
        return 0
    from controller.commands.simulated import simulated_campaign, simulation_settings

    name = f"demo-n{len(ids)}-seed{args.seed}" + ("-sequential" if args.sequential else "")
    quiet = args.json or not sys.stderr.isatty()
    settings = simulation_settings(seed=args.seed, hidden_errors=args.hidden_errors)
    Path(args.out).mkdir(exist_ok=True)  # the run folder (its parent checked above)
    summary, sim = simulated_campaign(cfg, args.config, Path(args.out), Path(args.out) / "campaign.db", ids,
                                      settings, name, sequential=args.sequential,
                                      quiet=quiet, library_dir=Path(args.out), nights=args.nights)
    coarse = summary["coarse_correction"]
    centroid_only_twin(coarse, cfg, Path(args.config), Path(args.out), sim, args)
    if args.uncalibrated is not None:
        u = uncalibrated_field(Path(args.config), Path(args.out), ids, args.seed, args.uncalibrated)
        # How many times longer a heliostat takes on the new field than on the near-calibrated one.
        fast, slow = summary["heliostats_per_hour"], u["heliostats_per_hour"]
        u["slowdown_vs_calibrated"] = round(fast / slow, 2) if fast and slow else None
        summary["coarse_correction_uncalibrated"] = u
    if args.json:
        # The demo's --json keys are a contract (docs/campaigns.md); the outcome is the exit code.
        print_json({k: v for k, v in summary.items() if k not in ("status", "cause")})
    else:
        _print_summary(summary, sim)
    return sim.exit_code  # a partial night is not a finished demo (3), however the campaign ended


def _print_aim(rows: list[dict]) -> None:
    print(f"{'id':5} {'source dir (ENU)':>28} {'aim normal (ENU)':>28} {'az deg':>9} {'el deg':>8}"
          f" {'az steps':>9} {'el steps':>9}")
    for r in rows:
        s = " ".join(f"{c:8.4f}" for c in r["source_dir"])
        m = " ".join(f"{c:8.4f}" for c in r["normal"])
        print(f"{r['heliostat']:5} {s:>28} {m:>28} {r['az_deg']:9.3f} {r['el_deg']:8.3f}"
              f" {r['az_steps']:>9} {r['el_steps']:>9}")


def _print_summary(s: dict, sim) -> None:
    from rich.console import Console
    from rich.table import Table

    from controller.reports.summary import ReferenceTruth

    result, safety = sim.result, sim.safety
    con = Console()
    d, u = sim.daytime, sim.daytime_uncalibrated
    con.print(f"[bold]daytime tracking error (open loop, sun path of 4 days, plant truth): RMS {d.rms:.2f} "
              f"mrad, p95 {d.p95:.2f}, max {d.max:.2f}[/bold] "
              f"(model-predicted from σ: RMS {sim.predicted.rms:.2f}, p95 {sim.predicted.p95:.2f}; "
              f"uncalibrated: RMS {u.rms:.2f}, p95 {u.p95:.2f})")
    if sim.nights:
        nt = Table(title="daytime error after each night (open loop, mrad)")
        for col in ("night", "status", "measured", "true RMS", "true p95", "predicted RMS", "predicted p95"):
            nt.add_column(col)
        for r in sim.nights:
            nt.add_row(str(r.night), r.summary.status, f"{r.measured}/{r.planned}", _f(r.daytime.rms, 2),
                       _f(r.daytime.p95, 2), _f(r.predicted.rms, 2), _f(r.predicted.p95, 2))
        con.print(nt)
    t = Table(title=f"campaign {result.name}" + (" (resumed)" if result.resumed else ""))
    failures = any(r.fault_cause for r in result.runs)
    for col in ("id", "status", "matched case (✓ = truth)", "it", "mrad before", "after", "target s") + (
            ("fault",) if failures else ()):
        t.add_column(col, no_wrap=col not in ("fault", "matched case (✓ = truth)"))
    for r in result.runs:
        truth = sim.truth.get(r.heliostat_id, ReferenceTruth(None, None, None))
        m = r.matched_label or "unknown"
        case = f"{m} ✓" if m == truth.label else f"{m} ✗ {truth.label}"
        row = [r.heliostat_id, r.status, case, str(r.iterations), _f(truth.error_before_mrad, 2),
               _f(truth.error_after_mrad, 2), _f(r.target_occupancy_s, 1)]
        t.add_row(*row, *([r.fault_cause or ""] if failures else []))
    con.print(t)
    con.print(f"simulated plant clock: {sim.settings.clock_speedup:g}x real time; the table's errors are "
              "true reflected-beam errors at the calibration geometry (closed loop)")
    con.print(f"campaign {s['status']}" + (f": {s['cause']}" if s["cause"] else ""))
    con.print(f"calibrated {s['calibrated']}/{s['heliostats']}, failed {s['failed']}; "
              "closed-loop error before "
              f"mean {_f(s['error_before_mrad']['mean'])} max {_f(s['error_before_mrad']['max'])} mrad, "
              f"after mean {_f(s['error_after_mrad']['mean'])} max {_f(s['error_after_mrad']['max'])} mrad")
    con.print(f"{_f(s['heliostats_per_hour'], 0)} heliostats/hour/target (plant time), mean target "
              f"occupancy {_f(s['target_occupancy_s_mean'], 1)} s, pipelined speedup "
              f"{_f(s['pipelined_speedup'], 2)}x")
    c = s["coarse_correction"]
    if c["threshold"] is not None:
        rerun = (f"the {len(c['centroid_only_rerun'])} with a coarse move calibrated again centroid only"
                 if c["centroid_only_rerun"] else "no coarse move: this run is its own centroid-only run")
        con.print(f"coarse correction (confidence ≥ {c['threshold']:g}): applied on {c['applied']} of "
                  f"{s['heliostats']} heliostats ({c['clipped_first_looks']} first looks clipped); "
                  f"iterations per heliostat {_f(c['iterations_mean'], 2)}, centroid only "
                  f"{_f(c['iterations_centroid_only_mean'], 2)} ({rerun})")
    if "coarse_correction_uncalibrated" in s:
        print_uncalibrated(con, s["coarse_correction_uncalibrated"])
    con.print(f"database {s['db']}, report {s['report']}")
    con.print(f"beam safety (plant truth): {safety['violations']} of {safety['samples']} samples "
              f"with two beams on the target; at most {safety['max_beams_on_target']} beam(s) on it")


def _f(v, nd: int = 3) -> str:
    return "-" if v is None else f"{v:.{nd}f}"
