"""``heliocal model prior``: a field's prior of the tracking-model terms, from fitted models.

Contract (scripts depend on it)::

    heliocal model prior MODEL.json... --out PRIOR.json [--json]

Each term's field mean and spread are the mean and standard deviation of its value over the
heliostats whose fit identified it; a term fewer than three fits identified keeps the documented
prior. ``heliocal model fit --prior PRIOR.json`` then fits a heliostat with a few
records against its field; ``calibration.model.field_prior`` gives it to the nights.
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser("prior", help="learn a field's prior of the terms from fitted models",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("models", nargs="+", metavar="MODEL.json", help="models written by 'heliocal model fit'")
    p.add_argument("--out", required=True, metavar="PRIOR.json", help="where to write the prior")
    p.add_argument("--json", action="store_true", help="print the prior document as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from controller.commands.common import output_file, print_json
    from controller.errors import InputError
    from controller.geometry.model.field_prior import field_prior
    from controller.geometry.model.field_prior_io import prior_document, write_prior
    from controller.geometry.model.tracking import NAMES, TERMS
    from controller.storage.model_file import read_model

    out = output_file(args.out)
    files = [read_model(m) for m in args.models]
    ids = [f.heliostat_id for f in files]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"model prior: more than one model of heliostat {', '.join(dup)}; give one each")
    values = np.array([f.model.values for f in files])
    identified = np.array([[n in f.identified for n in NAMES] for f in files])
    prior = field_prior(values, identified)
    doc = prior_document(prior, ids)
    write_prior(out, doc)
    if args.json:
        print_json(doc)
        return 0
    print(f"field prior from {len(files)} heliostats written to {out}")
    print(f"  {'term':<26}{'mean':>10}{'σ':>10}  identified by")
    for t, c in zip(TERMS, prior.count, strict=True):
        note = f"{c}" if c >= 3 else f"{c} (documented prior kept)"
        print(f"  {t.key:<26}{doc['terms'][t.key]:>10.3f}{doc['sigma'][t.key]:>10.3f}  {note}")
    return 0
