"""``heliocal campaign run --config C --db DB [--json]``: the calibration campaign (night 0);
``heliocal campaign night --config C --db DB [--simulate] [--seed S] [--json]``: tonight's
planned night (docs/nights.md); ``heliocal campaign list --db DB [--json]``: the nights and
campaigns recorded in a database; ``heliocal campaign flags --db DB [--clear IDS|all]``: the
geometries flagged after failing on two nights.

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

from controller.commands._id_lists import campaign_name
from controller.commands._numbers import SEED, Number
from controller.commands.campaigns._campaign_list import list_campaigns
from controller.commands.campaigns._flags import flags_command
from controller.commands.common import (
    add_config_option,
    add_field_change_option,
    add_hidden_errors_option,
    add_json_option,
    campaign_heliostats,
    check_db_field,
    output_dir,
    output_file,
    print_json,
)
from controller.io.json_files import dumps_json

DB_HELP = "campaign database (SQLite; created if missing, in an existing folder)"
SPEEDUP = Number(0, 1000, lo_open=True)  # the simulated plant clock's speedup (SimulationSettings)


def _add_simulation_options(parser) -> None:
    """--simulate and what it takes (seed, clock speedup, hidden errors): ``campaign run`` and
    ``campaign night`` alike."""
    parser.add_argument("--simulate", action="store_true", help="run against the embedded simulated plant")
    parser.add_argument("--seed", type=SEED, default=0, help="simulation seed (with --simulate; default 0)")
    parser.add_argument("--clock-speedup", type=SPEEDUP, default=20.0, metavar="X",
                        help="simulated plant seconds per wall second (with --simulate; default 20)")
    add_hidden_errors_option(parser)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "campaign", help="nightly calibration campaigns (run / resume)", description=__doc__.splitlines()[0]
    )
    sub = p.add_subparsers(dest="campaign_command", metavar="SUBCOMMAND")
    r = sub.add_parser("run", help="run or resume a campaign", description=__doc__)
    add_config_option(r)
    r.add_argument("--db", required=True, metavar="DB", help=DB_HELP)
    r.add_argument("--name", default=None, help="campaign name (default: <config stem>-<night>)")
    r.add_argument("--heliostats", default=None, metavar="IDS", help="comma-separated ids (default: all)")
    r.add_argument("--camera-manifest", default=None, metavar="FILE", help="replay frame pairs (FileCamera)")
    _add_simulation_options(r)
    r.add_argument("--report", default=None, metavar="DIR", help="also write the morning report into DIR")
    r.add_argument("--notify", default=None, metavar="CMD",
                   help="run CMD (a shell command) at the end with the summary JSON on its standard input")
    add_field_change_option(r)
    add_json_option(r)
    r.set_defaults(func=run)
    n = sub.add_parser("night", help="run or resume tonight's planned night",
                       description="Tonight's planned night on the configured field: plan from the models "
                                   "in DB (or reload the stored plan when resuming), change lamps in the "
                                   "dark, run the passes of every target in parallel, refit, summarise. "
                                   "Rerun after Ctrl-C or kill -9 to resume the same night.")
    add_config_option(n)
    n.add_argument("--db", required=True, metavar="DB", help=DB_HELP)
    n.add_argument("--heliostats", default=None, metavar="IDS", help="comma-separated ids (default: all)")
    n.add_argument("--camera-manifest", default=None, metavar="FILE",
                   help="replay frame pairs for the calibration target (FileCamera)")
    _add_simulation_options(n)
    n.add_argument("--strategy", default="design", choices=("design", "round-robin"),
                   help="planner strategy (default design: the daytime variance reduction)")
    add_field_change_option(n)
    add_json_option(n)
    n.set_defaults(func=run_night_command)
    ls = sub.add_parser("list", help="the nights and campaigns recorded in a database",
                        description="One block per night (its passes grouped), then campaigns outside "
                                    "any night: status and counts, one line each within 120 columns.")
    ls.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    ls.add_argument("--long", action="store_true",
                    help="every detail, lines not cut: each night's lamps and cause, each campaign's cause")
    add_json_option(ls)
    ls.set_defaults(func=list_campaigns)
    fl = sub.add_parser("flags", help="geometries flagged after failing on two nights; clear them",
                        description="The planned geometries that failed on two nights: not planned again "
                                    "until cleared (--clear IDS or all, optionally only under --lamp).")
    fl.add_argument("--db", required=True, metavar="DB", help="campaign database (SQLite)")
    fl.add_argument("--clear", default=None, metavar="IDS|all",
                    help="clear the flags of these heliostats (comma-separated ids, or all)")
    fl.add_argument("--lamp", default=None, metavar="LAMP", help="with --clear: only the flags under LAMP")
    add_json_option(fl)
    fl.set_defaults(func=flags_command)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def notify(command: str, summary: dict) -> None:
    """Hand the summary to a scheduler's hook; its failure is reported, never fatal (the
    campaign's outcome is already recorded)."""
    import subprocess

    try:
        r = subprocess.run(command, shell=True, input=dumps_json(summary), text=True, timeout=60,
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

    output_file(args.db, "--db")  # its folder exists: never created
    cfg = load_config(args.config)
    ids = campaign_heliostats(args, cfg)
    check_db_field(args.db, cfg, ids, args)  # the models in DB were fitted on this field
    name = campaign_name(args.name, "--name") if args.name is not None else default_name(args.config)
    quiet = args.json or not sys.stderr.isatty()
    db = Path(args.db)
    if args.report:
        output_dir(args.report, "--report")
    try:
        summary, result = _run(args, cfg, ids, name, quiet, db)
    except KeyboardInterrupt:
        _interrupted(args, db, name, cfg.lamps is not None)
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


def _interrupted(args: argparse.Namespace, db: Path, name: str, cfg_lamps: bool) -> None:
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
    lamps = "every lamp confirmed dark, " if args.simulate or cfg_lamps else ""  # else LampNotDark, exit 1
    print(f"heliocal campaign run: interrupted; {summary['recorded']} heliostat(s) recorded in {db}; "
          f"{lamps}heliostats in motion were parked. Rerun the same command to resume.", file=sys.stderr)
    if args.notify:
        notify(args.notify, summary)


def _run(args, cfg, ids, name, quiet, db):
    if args.simulate:
        from controller.commands.simulated import sim_dir, simulated_campaign, simulation_settings

        settings = simulation_settings(seed=args.seed, clock_speedup=args.clock_speedup,
                                      hidden_errors=args.hidden_errors)
        summary, sim = simulated_campaign(cfg, args.config, sim_dir(db), db, ids, settings, name, quiet=quiet)
        return summary, sim.result
    return _run_field(cfg, args, ids, name, quiet)


def _run_field(cfg, args, ids, name, quiet):
    from controller.calibration.campaign.runner import Campaign, CampaignOptions
    from controller.calibration.night.planned import calibration_night
    from controller.commands._progress import TerminalProgress
    from controller.commands.field import open_store, real_field
    from controller.reports.summary import summarize

    store = open_store(args.db)
    try:
        with real_field(cfg, args.config, store, camera_manifest=args.camera_manifest) as fs:
            campaign = Campaign(fs.field, CampaignOptions(name=name), heliostat_ids=ids,
                                observers=[] if quiet else [TerminalProgress()])
            result = calibration_night(fs.book, campaign)
        summary = summarize(store, result.campaign_id)
    finally:
        store.close()
    summary["db"] = str(args.db)
    return summary, result


def run_night_command(args: argparse.Namespace) -> int:
    from controller.commands.campaigns._night import run_night_cli

    return run_night_cli(args)
