"""``heliocal campaign run --config C --db DB [--json]``: a nightly calibration campaign.

Rerunning the same command after an interruption (even ``kill -9``) resumes the campaign in
the database: heliostats already recorded are skipped, the others are calibrated. The
campaign name defaults to ``<config stem>-<night>`` (the UTC date 12 h ago), so one night's
reruns resume and the next night starts a new campaign; ``--name`` overrides it.

The camera: ``--camera-manifest M`` replays recorded frame pairs (FileCamera); ``--simulate``
runs the campaign against the embedded simulated plant (firmware on ptys / Modbus TCP and the
simulated camera, as ``heliocal demo`` does), with the database where ``--db`` says.
"""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

from controller.commands._common import add_config_option, add_json_option, print_json
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "campaign", help="nightly calibration campaigns (run / resume)", description=__doc__.splitlines()[0]
    )
    sub = p.add_subparsers(dest="campaign_command", metavar="SUBCOMMAND")
    r = sub.add_parser("run", help="run or resume a campaign", description=__doc__)
    add_config_option(r)
    r.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite, created if missing)")
    r.add_argument("--name", default=None, help="campaign name (default: <config stem>-<night>)")
    r.add_argument("--heliostats", default=None, metavar="IDS", help="comma-separated ids (default: all)")
    r.add_argument("--camera-manifest", default=None, metavar="FILE", help="replay frame pairs (FileCamera)")
    r.add_argument("--simulate", action="store_true", help="run against the embedded simulated plant")
    r.add_argument("--seed", type=int, default=None, help="simulation seed (default: simulation.seed)")
    r.add_argument("--report", default=None, metavar="DIR", help="also write the morning report into DIR")
    add_json_option(r)
    r.set_defaults(func=run)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def default_name(config: str) -> str:
    night = (datetime.now(UTC) - timedelta(hours=12)).date().isoformat()
    return f"{Path(config).stem}-{night}"


def run(args: argparse.Namespace) -> int:
    from controller.config import load_config

    cfg = load_config(args.config)
    ids = [h.id for h in cfg.heliostats]
    if args.heliostats:
        ids = [i.strip() for i in args.heliostats.split(",") if i.strip()]
        for hid in ids:
            cfg.heliostat(hid)
    name = args.name or default_name(args.config)
    quiet = args.json or not sys.stderr.isatty()
    db = Path(args.db)
    if args.simulate:
        from controller.commands.demo import run_simulated

        seed = cfg.simulation.seed if args.seed is None else args.seed
        summary, result, _ = run_simulated(
            cfg, args.config, db.parent / f"{db.stem}-sim", db, ids, seed, name, quiet=quiet
        )
    else:
        if not args.camera_manifest:
            raise InputError(
                "campaign run: no camera; pass --camera-manifest FILE (recorded pairs) "
                "or --simulate (embedded simulated plant)"
            )
        summary, result = _run_field(cfg, args, ids, name, quiet)
    if args.report:
        from controller.reports.campaign import write_report
        from controller.storage.db import open_existing

        with open_existing(db) as store:
            summary["report"] = str(write_report(store, args.report, result.campaign_id))
    summary["campaign"] = name
    summary["resumed"] = result.resumed
    if args.json:
        print_json(summary)
    else:
        print(
            f"campaign {name}{' (resumed)' if result.resumed else ''}: calibrated {summary['calibrated']}/"
            f"{summary['heliostats']}, failed {summary['failed']}; database {db}"
        )
    return 0 if result.halted is None else 1


def _run_field(cfg, args, ids, name, quiet):
    from controller.calibration.campaign import Campaign, CampaignOptions, summarize
    from controller.calibration.library import load_library
    from controller.devices.factory import LinkPool
    from controller.devices.file_camera import FileCamera
    from controller.storage.db import CampaignStore

    camera = FileCamera(args.camera_manifest)
    lib = load_library(cfg.calibration.library) if cfg.calibration.library else None
    cal = cfg.calibration
    opts = CampaignOptions(
        name=name,
        pipeline_depth=cal.pipeline_depth,
        settle_s=cal.settle_s,
        progress=not quiet,
        image_dir=Path(args.db).parent / "images",
    )
    with CampaignStore(args.db) as store, LinkPool() as pool:
        result = Campaign(
            cfg, args.config, store, pool, camera, heliostat_ids=ids, library=lib, options=opts
        ).run()
        summary = summarize(store, result.campaign_id)
    summary["db"] = str(args.db)
    return summary, result
