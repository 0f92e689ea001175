"""``heliocal model refit``: every heliostat's tracking model refitted on all its measurements.

Contract (scripts depend on it)::

    heliocal model refit --config C --db DB [--heliostats IDS] [--workers N] [--json]
    -> {"heliostats", "refitted", "no_model", "measurements", "seconds", "workers", "db"}

Each heliostat of the database (or of ``--heliostats``) is fitted on every measurement
recorded for it, with the fit settings of ``calibration.model`` in C (noise, prior σ, age
half-life, drift), in ``--workers`` processes (default one per core), with the same models as
one at a time; the new models are recorded in one transaction, each as the model of its
heliostat's latest run. For after a change of ``calibration.model``, or to rebuild the models
of a field. ``no_model``: heliostats whose measurements support no fit (they keep their model).
Takes the database's campaign lock (exit 2 naming its owner when a campaign runs).
"""

from __future__ import annotations

import argparse

from controller.commands._id_lists import split_ids
from controller.commands._numbers import Number


def register(subparsers) -> None:
    from controller.commands.common import add_config_option, add_json_option

    p = subparsers.add_parser("refit", help="refit every heliostat's model on all its measurements",
                              description=__doc__.split("\n\n")[0])
    add_config_option(p)
    p.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    p.add_argument("--heliostats", default=None, metavar="IDS", help="comma-separated ids (default: all)")
    p.add_argument("--workers", type=Number(1, 256, integer=True), default=None, metavar="N",
                   help="worker processes (default: one per core for a large field)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    from controller.calibration.night.refit import refit_models
    from controller.commands.common import print_json
    from controller.commands.field import open_store
    from controller.config import load_config
    from controller.storage.db import open_existing
    from controller.storage.field_records import check_fit_inputs, measurements_by_heliostat, record_models

    open_existing(args.db).close()  # an existing heliocal database (not any file), before writing
    cfg = load_config(args.config)
    ids = None
    if args.heliostats:
        ids = split_ids(args.heliostats, "--heliostats", cfg.heliostat)  # before anything is read
    store = open_store(args.db)
    try:
        history = measurements_by_heliostat(store, ids)
        for hid in history:
            cfg.heliostat(hid)  # a heliostat recorded but no longer configured: refused, named
        check_fit_inputs(store.path, cfg, history)  # an edited record: refused, named
        r = refit_models(cfg, history, workers=args.workers)
        fitted = {hid: (history[hid][-1], m) for hid, m in r.models.items() if m is not None}
        record_models(store, fitted)
    finally:
        store.close()
    out = {"heliostats": len(history), "refitted": len(fitted),
           "no_model": sorted(hid for hid, m in r.models.items() if m is None),
           "measurements": sum(len(v) for v in history.values()), "seconds": r.seconds,
           "workers": args.workers, "db": str(args.db)}
    if args.json:
        print_json(out)
    else:
        print(f"refitted {out['refitted']} of {out['heliostats']} heliostats on {out['measurements']} "
              f"measurements in {out['seconds']:.1f} s; database {args.db}")
        if out["no_model"]:
            print(f"  no fit (kept their model): {', '.join(out['no_model'][:20])}"
                  + (f", … ({len(out['no_model'])})" if len(out["no_model"]) > 20 else ""))
    return 0
