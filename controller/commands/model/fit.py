"""``heliocal model fit``: fit a heliostat's tracking model to PAINT/ARTIST calibration records.

Contract (scripts depend on it)::

    heliocal model fit RECORD.json... --heliostat-properties PROPS.json --towers TOWERS.json
                       --out MODEL.json [--noise-mrad S] [--json]

Prints every term with its 1-σ (and whether the data identified it) and the training residuals;
``--json`` prints the MODEL.json document itself. Exit 2 on a bad file (named) or when the
records cannot support a fit.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controller.commands._numbers import Number


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit the tracking model to calibration records",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="+", metavar="RECORD.json", help="PAINT calibration-properties records")
    p.add_argument("--heliostat-properties", required=True, metavar="PROPS.json",
                   help="PAINT/ARTIST heliostat-properties file")
    p.add_argument("--towers", required=True, metavar="TOWERS.json", help="tower-measurements file (targets)")
    p.add_argument("--out", required=True, metavar="MODEL.json", help="where to write the fitted model")
    p.add_argument("--noise-mrad", type=Number(0, 100, lo_open=True), default=0.8, metavar="S",
                   help="1-σ noise of a measured mirror normal, mrad (default 0.8: the spread between "
                        "two focal-spot methods on the Jülich records)")
    p.add_argument("--json", action="store_true", help="print the model document as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands._common import output_file, print_json
    from controller.errors import InputError
    from controller.geometry.model_fit import fit_model
    from controller.geometry.paint_io import read_paint_set
    from controller.geometry.tracking_model import TERMS
    from controller.storage.model_file import model_document, write_model

    out = output_file(args.out)
    if not (args.noise_mrad > 0 and args.noise_mrad < 1e3):
        raise InputError(f"--noise-mrad must be a positive number of mrad, got {args.noise_mrad}")
    ps = read_paint_set(args.records, args.heliostat_properties, args.towers)
    hid, records = ps.heliostat_id, ps.records
    fit = fit_model(ps.kinematics, [r.sample for r in records], noise_mrad=args.noise_mrad)
    doc = model_document(hid, ps.properties, ps.towers.origin_wgs84, fit, noise_mrad=args.noise_mrad,
                         records=[Path(r).name for r in args.records])
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
    res = ", ".join(f"{r:.2f}" for r in fit.residual_mrad)
    print(f"  training residual (normal, mrad): {res}; RMS {fit.residual_mrad_rms:.3f} "
          f"(nominal {fit.initial_residual_mrad_rms:.3f})")
    if not fit.converged:
        print("  warning: the fit did not settle within its step limit; check the records for outliers",
              file=sys.stderr)
    return 0
