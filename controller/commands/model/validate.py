"""``heliocal model validate``: the open-loop error of the tracking model on records it was not
fitted to, against the rigid-rotation peer and the two focal-spot methods' disagreement.

::

    heliocal model validate RECORD.json... --heliostat-properties PROPS.json --towers TOWERS.json
                            [--split loo|time|first|azimuth|solstice|balanced|knn] [--train N] [--val N]
                            [--timestamps TS.json] [--prior PRIOR.json] [--json] [--plot DIR]
    heliocal model validate --paint-dir DIR [--heliostats IDS] [--split ...] ... [--plot DIR]

``loo`` (one heliostat's records; the default there): fit on all but one, predict it, every
way round. A split (docs/tracking-model.md, "Validation"; the default for a PAINT folder is
``time``): fit on its training records, predict every other record it holds out; per heliostat
the median held-out error of the model, of a rigid rotation of the nominal normals fitted to
the same records, of the nominal kinematics, and the UTIS/HeliOS floor; over a field the median
of the heliostats' medians. ``--plot DIR`` draws the per-heliostat errors, the spread of the
terms across the field and each heliostat's drift over time.
"""

from __future__ import annotations

import argparse

from controller.commands._numbers import Number

SPLIT_CHOICES = ("loo", "time", "first", "azimuth", "solstice", "balanced", "knn")


def register(subparsers) -> None:
    p = subparsers.add_parser("validate", help="held-out open-loop error of the tracking model on records",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="*", metavar="RECORD.json", help="PAINT calibration-properties records")
    p.add_argument("--heliostat-properties", metavar="PROPS.json",
                   help="PAINT/ARTIST heliostat-properties file")
    p.add_argument("--towers", metavar="TOWERS.json", help="tower-measurements file (default: the folder's)")
    p.add_argument("--paint-dir", metavar="DIR", help="a PAINT-layout folder: validate every heliostat in it")
    p.add_argument("--heliostats", metavar="IDS", help="with --paint-dir: comma-separated ids (default: all)")
    p.add_argument("--split", choices=SPLIT_CHOICES, default=None,
                   help="loo (default for records), time (default for --paint-dir), first, azimuth, "
                        "solstice, balanced, knn")
    p.add_argument("--train", type=Number(1, 100000, integer=True), default=20, metavar="N",
                   help="training records per heliostat (default 20)")
    p.add_argument("--val", type=Number(1, 100000, integer=True), default=10, metavar="N",
                   help="held-out records: the last N (time, first), validation records (azimuth, solstice), "
                        "clusters (balanced) or the sparsest N twice (knn) (default 10)")
    p.add_argument("--timestamps", metavar="TS.json", help="PAINT timestamps (default: the folder's)")
    p.add_argument("--prior", metavar="PRIOR.json",
                   help="a field's prior of the terms ('heliocal model prior')")
    p.add_argument("--noise-mrad", type=Number(0, 100, lo_open=True), default=0.8, metavar="S",
                   help="1-σ noise of a measured mirror normal, mrad (default 0.8)")
    p.add_argument("--plot", metavar="DIR", help="write the validation figures into DIR")
    p.add_argument("--json", action="store_true", help="print the tables as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.commands.common import print_json
    from controller.commands.model._validation import (
        field_report,
        full_fits,
        loo_report,
        paint_sets,
        print_field,
    )
    from controller.errors import InputError

    if args.paint_dir and args.records:
        raise InputError("model validate: give records or --paint-dir, not both")
    if not args.paint_dir and not args.records:
        raise InputError("model validate: give records (with --heliostat-properties) or --paint-dir DIR")
    split = args.split or ("time" if args.paint_dir else "loo")
    if split == "loo":
        if args.paint_dir:
            raise InputError("model validate: leave-one-out takes one heliostat's records, not --paint-dir")
        out = loo_report(args)
        if args.json:
            print_json(out)
        return 0
    sets = paint_sets(args)
    report = field_report(sets, split, args)
    if args.plot:
        from controller.reports.model_figures import write_validation_figures

        report["figures"] = write_validation_figures(args.plot, report, full_fits(sets, args))
    if args.json:
        print_json(report)
    else:
        print_field(report)
    return 0
