"""``heliocal reprocess``: re-analyse every stored frame pair with the current beam chain and refit
every heliostat's tracking model, on a Dask cluster, into a new database.

Contract (scripts depend on it, docs/reprocess.md)::

    heliocal reprocess --db DB --out NEW.db [--images DIR] [--since DATE]
                       [--scheduler ADDRESS [--connect-timeout S] | --workers N] [--json]

DB and the frame archive are opened read-only and never modified. A rerun with the same --out
continues where an interrupted one stopped. Prints the figures (``--json``: one object with
at least pairs, measurements, heliostats, models_refit, changed, workers, scheduler, wall_s) and
writes a diff report beside NEW.db. Exit 0 done; 1 the cluster failed; 2 bad input; 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from controller.commands._numbers import Number
from controller.commands.common import add_json_option

MAX_WORKERS = 256
CONNECT_TIMEOUT_S = 30.0  # Dask's own default connect timeout (distributed.comm.timeouts.connect)


def register(subparsers) -> None:
    p = subparsers.add_parser("reprocess", help="re-analyse the frame archive and refit every model (Dask)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--db", required=True, metavar="DB", help="source database (opened read-only)")
    p.add_argument("--out", required=True, metavar="NEW.db",
                   help="the new database (created; the same file again continues an interrupted run)")
    p.add_argument("--images", default=None, metavar="DIR",
                   help="the archive's folder when it moved: frames are read from DIR/<campaign>/<file> "
                        "(default: the paths the database recorded)")
    p.add_argument("--since", default=None, metavar="DATE",
                   help="re-analyse only pairs measured at or after DATE (ISO 8601, UTC unless a zone is "
                        "given); every heliostat is refitted")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler tcp://HOST:PORT (or tls://) to run on (default: a local cluster)")
    p.add_argument("--connect-timeout", type=Number(0, 600, lo_open=True), default=CONNECT_TIMEOUT_S,
                   metavar="S", help="seconds for --scheduler to answer as a Dask scheduler, name lookup "
                                     f"and connection included, before any work is sent (default "
                                     f"{CONNECT_TIMEOUT_S:g})")
    p.add_argument("--workers", type=Number(1, MAX_WORKERS, integer=True), default=None, metavar="N",
                   help="worker processes of the local cluster (default: the machine's cores)")
    add_json_option(p)
    p.set_defaults(func=run)


def parse_since(text: str) -> datetime:
    """An ISO 8601 date or date-time; UTC unless it names a zone. InputError otherwise."""
    from controller.errors import InputError

    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise InputError(f"--since {text!r}: expected an ISO 8601 date or date-time (2026-06-21, "
                         "2026-06-21T18:00:00Z)") from None
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def _check(args: argparse.Namespace) -> tuple[Path, Path, datetime | None, str | None, int]:
    """Every option checked before anything is opened or started."""
    from controller.calibration.reprocess.scheduler import parse_scheduler_address, tls_context
    from controller.commands.common import output_file
    from controller.errors import InputError

    if args.scheduler is not None and args.workers is not None:
        raise InputError("--scheduler and --workers exclude each other (the cluster has its own workers)")
    workers = args.workers if args.workers is not None else min(os.cpu_count() or 1, MAX_WORKERS)
    if args.scheduler is not None:
        tls_context(parse_scheduler_address(args.scheduler))
    since = parse_since(args.since) if args.since is not None else None
    images = None
    if args.images is not None:
        if not Path(args.images).is_dir():
            raise InputError(f"--images {args.images}: not a folder")
        images = os.path.abspath(args.images)
    db = Path(args.db)
    if not db.is_file():
        raise InputError(f"database not found: {db}")
    out = output_file(args.out)
    if out.exists() and out.resolve() == db.resolve():
        raise InputError(f"--out {out}: is the source database; reprocessing never writes into it")
    return db, out, since, images, workers


def run(args: argparse.Namespace) -> int:
    from controller.calibration.reprocess.plan import check_records, in_scope, load_configs
    from controller.calibration.reprocess.run import open_cluster, reprocess
    from controller.calibration.reprocess.scheduler import check_scheduler
    from controller.commands.common import print_json
    from controller.reports.reprocess import summary, write_report
    from controller.storage.db import open_existing
    from controller.storage.reprocess.archive import fingerprint, read_archive
    from controller.storage.reprocess.db import open_output

    t0 = time.monotonic()
    db_path, out, since, images, workers = _check(args)
    if args.scheduler is not None:
        # Before the output exists: a peer that is not a Dask scheduler leaves nothing behind.
        check_scheduler(args.scheduler, args.connect_timeout)
    options = {"since": since.isoformat() if since else None, "images": images}
    with open_existing(db_path) as source:
        archive = read_archive(source)
        configs = load_configs(archive)
        check_records(archive, configs)
        scope = in_scope(archive, since)
        fp = fingerprint(db_path)
        quiet = args.json or not sys.stderr.isatty()
        extra = {"workers": 0, "scheduler": None, "local": None}
        with open_output(source, out, fp, options) as db:
            resumed = len(db.done_pairs())
            if db.run_info()["status"] != "finished":
                with open_cluster(args.scheduler, workers, connect_timeout_s=args.connect_timeout) as cluster:
                    extra = {"workers": cluster.workers, "scheduler": cluster.address, "local": cluster.local}
                    with _progress(quiet) as progress:
                        reprocess(cluster, archive, configs, scope, db, images_dir=images, progress=progress)
                figures = _figures(summary(db), args, out, configs, options, resumed)
                db.apply(archive.latest_run, figures)
            figures = _figures(summary(db), args, out, configs, options, resumed)
            report = write_report(db, out.with_name(out.stem + "-report"), figures)
    figures.update(extra, report=str(report), wall_s=round(time.monotonic() - t0, 3))
    if args.json:
        print_json(figures)
        return 0
    _print(figures)
    return 0


def _figures(s: dict, args, out: Path, configs, options: dict, resumed: int) -> dict:
    return {**s, "db": str(args.db), "out": str(out), "since": options["since"], "images": options["images"],
            "resumed_pairs": resumed, "config_changed": list(configs.changed)}


def _print(f: dict) -> None:
    day, shift = f["daytime_predicted_mrad"], f["centroid_shift_mm"]

    def n(v, d=3):
        return "–" if v is None else f"{v:.{d}f}"

    where = f"{f['workers']} worker(s), scheduler {f['scheduler'] or 'none: already finished'}"
    print(f"heliocal reprocess: {f['pairs']} frame pair(s) of {f['db']} → {f['out']} "
          f"({where}, {f['wall_s']:.1f} s)")
    print(f"  re-analysed with a beam {f['measurements']}, no beam now {f['no_beam']}, "
          f"missing {f['missing']}, unreadable {f['unreadable']}")
    ids = ", ".join(f["changed"][:10]) + (" …" if len(f["changed"]) > 10 else "")
    print(f"  heliostats {f['heliostats']}: models refitted {f['models_refit']}, changed by more than σ "
          f"{len(f['changed'])}" + (f" ({ids})" if ids else ""))
    print(f"  centroid shift median/p95/max {n(shift['median'], 2)}/{n(shift['p95'], 2)}/"
          f"{n(shift['max'], 2)} mm; predicted daytime error {n(day['old'])} → {n(day['new'])} mrad")
    print(f"  report: {f['report']}")


class _progress:
    """A rich progress bar per phase on stderr (nothing when ``quiet``)."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self._p = None
        self._tasks: dict[str, int] = {}

    def __enter__(self):
        if not self.quiet:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self._p = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                               TextColumn("ETA"), TimeRemainingColumn(), transient=False)
            self._p.start()
        return self

    def __call__(self, phase: str, done: int, total: int) -> None:
        if self._p is None:
            return
        if phase not in self._tasks:
            self._tasks[phase] = self._p.add_task(phase, total=total)
        self._p.update(self._tasks[phase], completed=done, total=total)

    def __exit__(self, *exc) -> None:
        if self._p is not None:
            self._p.stop()
