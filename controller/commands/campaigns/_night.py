"""``heliocal campaign night``: tonight's planned night on the configured (or simulated) field.

The night itself is the product's :class:`controller.calibration.night.planned.PlannedNight`; this
module opens the database, picks tonight's night (the unfinished one to resume, else the next
index, named ``<night 0's name>/night-<k>``), builds the field and prints the summary. With
``--simulate`` the field is the embedded simulated plant on that night
(:mod:`controller.commands.simulated`), and the summary adds the true daytime error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from controller.commands.common import campaign_heliostats, check_db_field, output_file, print_json
from controller.errors import InputError


def run_night_cli(args: argparse.Namespace) -> int:
    from controller.commands.field import open_store
    from controller.config import load_config
    from controller.storage.nights import NightBook

    output_file(args.db, "--db")  # its folder exists: never created
    cfg = load_config(args.config)
    ids = campaign_heliostats(args, cfg)
    if not args.simulate and cfg.lamps is None:
        raise InputError(f"{args.config}: lamps: a planned night switches lamps in the dark and confirms "
                         "each one lit; configure the lamp panel (lamps:, docs/lamps.md)")
    check_db_field(args.db, cfg, ids, args)  # tonight's plan starts from models fitted on this field
    db = Path(args.db)
    quiet = args.json or not sys.stderr.isatty()
    progress = None if quiet else (lambda text: print(text, file=sys.stderr))
    store = open_store(db)
    refused = None
    try:
        book = NightBook(store)
        base = book.base_name() or Path(args.config).stem
        try:
            summary, code = (_simulated(args, cfg, store, ids, base, progress) if args.simulate
                             else _field(args, cfg, store, book, ids, base, progress))
        except KeyboardInterrupt:
            lamps = "every lamp confirmed dark, " if args.simulate or cfg.lamps is not None else ""
            print(f"heliocal campaign night: interrupted; {lamps}heliostats in motion parked. Rerun the same "
                  "command to resume the night.", file=sys.stderr)
            return 130
    except BaseException as exc:
        refused = exc
        raise
    finally:
        store.close(refused)  # a refusal on a database this run created leaves no file
    summary["db"] = str(db)
    if args.json:
        print_json(summary)
    else:
        p = summary["daytime_error_predicted_mrad"]
        lamps = ", ".join(x["lamp"] for x in summary["lamps"]) or "none"
        cause = f" ({summary['cause']})" if summary["cause"] else ""
        print(f"night {summary['night']} ({summary['name']}): {summary['measured']}/{summary['planned']} "
              f"geometries measured; lamps {lamps}; predicted daytime RMS {p['rms']:.2f} mrad; "
              f"status {summary['status']}{cause}; database {db}")
        for u in summary.get("unmeasurable", []):
            print(f"  {u['heliostat']}: {u['why']}")
    if summary["status"] == "aborted":
        print(f"heliocal campaign night: {summary['cause']}", file=sys.stderr)
    return code


def _field(args, cfg, store, book, ids, base, progress) -> tuple[dict, int]:
    from controller.calibration.night.planned import PlannedNight, tonight
    from controller.commands.field import real_field

    name, index = tonight(book, base)
    with real_field(cfg, args.config, store, camera_manifest=args.camera_manifest) as fs:
        s = PlannedNight(fs.field, fs.book, name, index, heliostat_ids=ids, strategy=args.strategy,
                         progress=progress).run()
    return s.to_json(), s.exit_code


def _simulated(args, cfg, store, ids, base, progress) -> tuple[dict, int]:
    from controller.commands.simulated import planned_night, sim_dir, simulation_settings

    first = store.campaign_by_name(base)
    seed = None if first is None else first.meta.get("seed")
    if seed is not None and seed != args.seed:
        raise InputError(f"--seed {args.seed}: {args.db} was calibrated on the simulated plant with "
                         f"seed {seed}")
    report = planned_night(cfg, args.config, store, sim_dir(Path(args.db)), ids,
                           simulation_settings(seed=args.seed, clock_speedup=args.clock_speedup,
                                              hidden_errors=args.hidden_errors), base,
                           progress=progress,
                           strategy=args.strategy)
    summary = {**report.summary.to_json(), "daytime_error_mrad": report.daytime.to_json()}
    return summary, report.summary.exit_code
