"""``heliocal campaign run --config C --db DB [--json]``: a nightly calibration campaign;
``heliocal campaign list --db DB [--json]``: the campaigns recorded in a database.

Rerunning the same command after an interruption (even ``kill -9``) resumes the campaign in
the database: heliostats already recorded are skipped, the others are calibrated. The
campaign name defaults to ``<config stem>-<night>`` (the UTC date 12 h ago), so one night's
reruns resume and the next night starts a new campaign; ``--name`` overrides it.

The camera: ``--camera-manifest M`` replays recorded frame pairs (FileCamera), else the
configuration's ``camera.driver`` (gige: GigE Vision imagers, docs/camera.md); ``--simulate``
runs the campaign against the embedded simulated plant (firmware on ptys / Modbus TCP and the
simulated camera, as ``heliocal demo`` does), with the database where ``--db`` says.
"""

from __future__ import annotations

import argparse
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

from controller.commands._common import add_config_option, add_json_option, output_dir, print_json
from controller.commands._numbers import SEED
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
    r.add_argument("--seed", type=SEED, default=0, help="simulation seed (with --simulate; default 0)")
    r.add_argument("--report", default=None, metavar="DIR", help="also write the morning report into DIR")
    r.add_argument("--notify", default=None, metavar="CMD",
                   help="run CMD (a shell command) at the end with the summary JSON on its standard input")
    add_json_option(r)
    r.set_defaults(func=run)
    ls = sub.add_parser("list", help="the campaigns recorded in a database",
                        description="One line per campaign: id, name, night, status, counts.")
    ls.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    add_json_option(ls)
    ls.set_defaults(func=list_campaigns)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def list_campaigns(args: argparse.Namespace) -> int:
    from controller.storage.db import open_existing

    rows = []
    with open_existing(args.db) as store:
        for c in store.campaigns():
            runs = store.runs(c.id)
            rows.append({"id": c.id, "name": c.name, "night": c.started_utc[:10], "status": c.status,
                         "cause": c.cause, "heliostats": len(c.queue), "recorded": len(runs),
                         "calibrated": sum(r.status == "calibrated" for r in runs)})
    if args.json:
        print_json({"campaigns": rows})
        return 0
    if not rows:
        print(f"{args.db}: no campaign recorded")
        return 0
    print(f"{'id':>4}  {'name':30} {'night':10}  {'status':11} {'calibrated':>10} {'recorded':>8}  cause")
    for r in rows:
        print(f"{r['id']:>4}  {r['name'][:30]:30} {r['night']:10}  {r['status']:11} "
              f"{r['calibrated']:>4}/{r['heliostats']:<5} {r['recorded']:>8}  {r['cause'] or ''}")
    return 0


def notify(command: str, summary: dict) -> None:
    """Hand the summary to a scheduler's hook; its failure is reported, never fatal (the
    campaign's outcome is already recorded)."""
    import json
    import subprocess

    try:
        r = subprocess.run(command, shell=True, input=json.dumps(summary), text=True, timeout=60,
                           capture_output=True)
    except subprocess.TimeoutExpired:
        print(f"heliocal campaign run: --notify command did not finish within 60 s: {command}",
              file=sys.stderr)
        return
    if r.returncode != 0:
        print(f"heliocal campaign run: --notify command exited {r.returncode}: {command}", file=sys.stderr)


def default_name(config: str) -> str:
    night = (datetime.now(UTC) - timedelta(hours=12)).date().isoformat()
    return f"{Path(config).stem}-{night}"


def run(args: argparse.Namespace) -> int:
    from controller.config import load_config

    cfg = load_config(args.config)
    ids = [h.id for h in cfg.heliostats]
    if args.heliostats is not None:
        ids = [i.strip() for i in args.heliostats.split(",") if i.strip()]
        if not ids:
            raise InputError(f"--heliostats: no heliostat id in {args.heliostats!r} "
                             "(give ids separated by commas)")
        if len(set(ids)) != len(ids):
            raise InputError(f"--heliostats: an id is given twice in {args.heliostats!r}")
        for hid in ids:
            cfg.heliostat(hid)
    name = args.name or default_name(args.config)
    quiet = args.json or not sys.stderr.isatty()
    db = Path(args.db)
    if args.simulate and args.camera_manifest:
        raise InputError("--simulate uses the simulated plant's camera; --camera-manifest cannot be given "
                         "with it")
    if args.report:
        output_dir(args.report, "--report")
    try:
        summary, result = _run(args, cfg, ids, name, quiet, db)
    except KeyboardInterrupt:
        _interrupted(args, db, name)
        return 130
    summary["campaign"] = name
    summary["resumed"] = result.resumed
    if args.report:
        from controller.reports.campaign import write_report
        from controller.storage.db import open_existing

        with open_existing(db) as store:
            summary["report"] = str(write_report(store, args.report, result.campaign_id))
    if args.json:
        print_json(summary)
    else:
        print(
            f"campaign {name}{' (resumed)' if result.resumed else ''}: calibrated {summary['calibrated']}/"
            f"{summary['heliostats']}, failed {summary['failed']}; status {summary['status']}"
            + (f" ({summary['cause']})" if summary["cause"] else "") + f"; database {db}"
        )
    if args.notify:
        notify(args.notify, summary)
    return result.exit_code


def _interrupted(args: argparse.Namespace, db: Path, name: str) -> None:
    """Ctrl-C / SIGTERM: the runner parked what moved and recorded the campaign as interrupted;
    say how far it got and how to go on."""
    from controller.reports.summary import summarize
    from controller.storage.db import open_existing

    summary = {"campaign": name, "status": "interrupted", "recorded": 0}
    if db.is_file():
        with open_existing(db) as store:
            camp = store.campaign_by_name(name)
            if camp is not None:
                summary.update(summarize(store, camp.id), campaign=name, recorded=len(store.runs(camp.id)))
    if args.json:
        print_json(summary)
    print(f"heliocal campaign run: interrupted; {summary['recorded']} heliostat(s) recorded in {db}; "
          "heliostats in motion were parked. Rerun the same command to resume.", file=sys.stderr)
    if args.notify:
        notify(args.notify, summary)


def _run(args, cfg, ids, name, quiet, db):
    if args.simulate:
        from controller.commands.demo import simulated_campaign
        from simplant.settings import SimulationSettings

        summary, sim = simulated_campaign(cfg, args.config, db.parent / f"{db.stem}-sim", db, ids,
                                          SimulationSettings(seed=args.seed), name, quiet=quiet)
        return summary, sim.result
    if not args.camera_manifest and cfg.camera.driver is None:
        raise InputError(
            "campaign run: no camera; pass --camera-manifest FILE (recorded pairs), set camera.driver "
            "in the configuration (docs/camera.md) or pass --simulate (embedded simulated plant)"
        )
    return _run_field(cfg, args, ids, name, quiet)


def _run_field(cfg, args, ids, name, quiet):
    from contextlib import closing

    from controller.calibration.runner import Campaign, CampaignOptions
    from controller.commands._progress import TerminalProgress
    from controller.config import config_sha256
    from controller.devices.factory import LinkPool, open_camera
    from controller.recognition.library_io import load_library
    from controller.reports.summary import summarize
    from controller.storage.db import CampaignStore
    from controller.storage.images import ImageArchive

    camera = open_camera(cfg.camera, args.camera_manifest)
    lib = load_library(cfg.calibration.library) if cfg.calibration.library else None
    cal = cfg.calibration
    opts = CampaignOptions(name=name, pipeline_depth=cal.pipeline_depth, settle_s=cal.settle_s)
    with CampaignStore(args.db) as store, LinkPool() as pool, closing(camera):
        store.campaign_lock.acquire()
        result = Campaign(
            cfg, args.config, store, pool, camera, config_sha256=config_sha256(args.config),
            heliostat_ids=ids, library=lib, options=opts,
            images=ImageArchive(Path(args.db).parent / "images"),
            observers=[] if quiet else [TerminalProgress()],
        ).run()
        summary = summarize(store, result.campaign_id)
    summary["db"] = str(args.db)
    return summary, result
