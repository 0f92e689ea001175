"""``heliocal model fit``: fit a heliostat's tracking model to PAINT/ARTIST calibration records.

Contract (scripts depend on it)::

    heliocal model fit RECORD.json... --heliostat-properties PROPS.json --towers TOWERS.json
                       --out MODEL.json [--prior PRIOR.json] [--timestamps TS.json]
                       [--noise-mrad S] [--drift-mrad D] [--json]

Prints every term with its 1-σ (and whether the data identified it) and the training residuals;
``--json`` prints the MODEL.json document itself. With ``--timestamps`` (PAINT's
``timestamps.json``) the joint references drift as a random walk between the records' sessions
and the model is that of the newest session. Exit 2 on a bad file (named) or when the records
cannot support a fit. What the fit had to decide (a record with one focal-spot method only, a
record without a time, an actuator whose properties leave its triangle) is said on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controller.commands._numbers import Number

DRIFT_MRAD = 0.1


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit the tracking model to calibration records",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="+", metavar="RECORD.json", help="PAINT calibration-properties records")
    p.add_argument("--heliostat-properties", required=True, metavar="PROPS.json",
                   help="PAINT/ARTIST heliostat-properties file")
    p.add_argument("--towers", required=True, metavar="TOWERS.json", help="tower-measurements file (targets)")
    p.add_argument("--out", required=True, metavar="MODEL.json", help="where to write the fitted model")
    p.add_argument("--prior", metavar="PRIOR.json", default=None,
                   help="a field's prior of the terms ('heliocal model prior'); default: the documented one")
    p.add_argument("--timestamps", metavar="TS.json", default=None,
                   help="PAINT timestamps file (\"<heliostat>_<id>\": UTC time): fit the references' drift")
    p.add_argument("--noise-mrad", type=Number(0, 100, lo_open=True), default=0.8, metavar="S",
                   help="1-σ noise of a measured mirror normal, mrad (default 0.8: the spread of a record "
                        "about a smooth model on the Jülich records)")
    p.add_argument("--drift-mrad", type=Number(0, 100), default=DRIFT_MRAD, metavar="D",
                   help=f"random walk of the joint references, mrad per √day, with --timestamps (default "
                        f"{DRIFT_MRAD:g}: measured on 16 Jülich heliostats; 0: no drift)")
    p.add_argument("--json", action="store_true", help="print the model document as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands.common import output_file, print_json
    from controller.geometry.model.drift import PAINT_JUMP_RAD, RandomWalk
    from controller.geometry.model.field_prior_io import read_prior
    from controller.geometry.model.fit import fit_model
    from controller.geometry.model.tracking import TERMS, TrackingModel
    from controller.geometry.paint_io import read_paint_set, read_timestamps
    from controller.storage.model_file import model_document, write_model

    out = output_file(args.out)
    prior = read_prior(args.prior) if args.prior else None
    stamps = read_timestamps(args.timestamps) if args.timestamps else None
    ps = read_paint_set(args.records, args.heliostat_properties, args.towers, timestamps=stamps,
                        methods=("UTIS", "HeliOS"))
    hid, records = ps.heliostat_id, ps.records
    walk = None
    if stamps:
        walk = RandomWalk(args.drift_mrad * 1e-3, PAINT_JUMP_RAD if args.drift_mrad > 0 else 0.0)
    fit = fit_model(ps.kinematics, [r.sample for r in records], noise_mrad=args.noise_mrad,
                    prior=TrackingModel(prior.mean) if prior else None,
                    prior_sigma=prior.sigma if prior else None, drift=walk)
    for note in (*ps.notes, *fit.notes):
        print(f"heliocal: {note}", file=sys.stderr)
    doc = model_document(hid, ps.properties, ps.towers.origin_wgs84, fit, noise_mrad=args.noise_mrad,
                         records=[Path(r).name for r in args.records], prior=prior,
                         prior_source=Path(args.prior).name if args.prior else "default", walk=walk,
                         times=[r.sample.time_days for r in records] if stamps else None)
    write_model(out, doc)
    if args.json:
        print_json(doc)
        return 0
    print(f"{hid}: tracking model fitted to {len(records)} record(s), written to {out}")
    print(f"  {'term':<26}{'value':>10}{'1-σ':>10}  identified")
    sig = fit.sigma_dict()
    for t in TERMS:
        mark = "yes" if t.name in fit.identified_terms() else "no (prior)"
        print(f"  {t.key:<26}{doc['terms'][t.key]:>10.3f}{sig[t.key]:>10.3f}  {mark}")
    res = ", ".join(f"{r:.2f}" for r in fit.residual_mrad[:40]) + (", …" if len(records) > 40 else "")
    print(f"  training residual (normal, mrad): {res}; RMS {fit.residual_mrad_rms:.3f} "
          f"(nominal {fit.initial_residual_mrad_rms:.3f})")
    if doc["drift"]:
        print(f"  {len(doc['drift']['sessions'])} sessions; the model is that of the newest, "
              f"{doc['drift']['reference_time_utc']}")
    if not fit.converged:
        print("  warning: the fit did not settle within its step limit; check the records for outliers",
              file=sys.stderr)
    return 0
