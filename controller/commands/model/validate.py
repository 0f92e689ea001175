"""``heliocal model validate``: leave-one-out open-loop error of the tracking model on records.

::

    heliocal model validate RECORD.json... --heliostat-properties PROPS.json --towers TOWERS.json [--json]

For each record: fit on the others, predict it, and report the held-out error of the mirror
normal beside the uncalibrated one (mrad), and where the record has two focal-spot methods
their disagreement — the floor the data can show.
"""

from __future__ import annotations

import argparse

from controller.commands._numbers import Number


def register(subparsers) -> None:
    p = subparsers.add_parser("validate", help="leave-one-out open-loop error on calibration records",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="+", metavar="RECORD.json",
                   help="PAINT calibration-properties records (≥ 2)")
    p.add_argument("--heliostat-properties", required=True, metavar="PROPS.json",
                   help="PAINT/ARTIST heliostat-properties file")
    p.add_argument("--towers", required=True, metavar="TOWERS.json", help="tower-measurements file (targets)")
    p.add_argument("--noise-mrad", type=Number(0, 100, lo_open=True), default=0.8, metavar="S",
                   help="1-σ noise of a measured mirror normal, mrad (default 0.8)")
    p.add_argument("--json", action="store_true", help="print the table as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from controller.commands._common import print_json
    from controller.errors import InputError
    from controller.geometry.aiming import aim_normal, angle_mrad
    from controller.geometry.paint_io import read_paint_set
    from controller.geometry.validation import leave_one_out

    if not (args.noise_mrad > 0 and args.noise_mrad < 1e3):
        raise InputError(f"--noise-mrad must be a positive number of mrad, got {args.noise_mrad}")
    ps = read_paint_set(args.records, args.heliostat_properties, args.towers)
    kin, records = ps.kinematics, ps.records
    folds = leave_one_out(kin, [r.sample for r in records], noise_mrad=args.noise_mrad)
    rows = []
    for f, r in zip(folds, records, strict=True):
        floor = None
        if "HeliOS" in r.focal_spots:
            c = kin.mirror_center(r.sample.az_steps, r.sample.el_steps)
            floor = float(angle_mrad(aim_normal(r.sample.source_dir, c, r.focal_spots["UTIS"]),
                                     aim_normal(r.sample.source_dir, c, r.focal_spots["HeliOS"])))
        rows.append({"record": Path(r.source).name, "held_out_mrad": f.held_out_mrad,
                     "uncalibrated_mrad": f.uncalibrated_mrad, "methods_disagree_mrad": floor,
                     "identified": f.fit.identified_terms()})
    held = np.array([r["held_out_mrad"] for r in rows])
    unc = np.array([r["uncalibrated_mrad"] for r in rows])
    summary = {"held_out_rms_mrad": float(np.sqrt(np.mean(held**2))),
               "uncalibrated_rms_mrad": float(np.sqrt(np.mean(unc**2))),
               "worst_ratio": float(np.min(unc / np.maximum(held, 1e-9)))}
    if args.json:
        print_json({"folds": rows, **summary})
        return 0
    print(f"  {'held-out record':<40}{'held-out':>10}{'uncal.':>10}{'UTIS/HeliOS':>13}  (normal error, mrad)")
    for r in rows:
        fl = "-" if r["methods_disagree_mrad"] is None else f"{r['methods_disagree_mrad']:.2f}"
        print(f"  {r['record']:<40}{r['held_out_mrad']:>10.2f}{r['uncalibrated_mrad']:>10.2f}{fl:>13}")
    print(f"  RMS {summary['held_out_rms_mrad']:.2f} mrad held out vs {summary['uncalibrated_rms_mrad']:.2f} "
          f"uncalibrated; every record at least {summary['worst_ratio']:.1f}x better")
    return 0
