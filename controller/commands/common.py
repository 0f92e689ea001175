"""Helpers shared by the CLI command modules: JSON output, --config option, file checks."""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from controller.errors import InputError
from controller.io.json_files import dumps_json

# The demo plant's configuration ships inside the package, so every command works from any
# folder; configs/demo.yaml in the repository is the same file.
PACKAGED_CONFIG = str(Path(__file__).resolve().parents[1] / "data" / "demo.yaml")
CONFIG_ENV = "HELIOCAL_CONFIG"
DEFAULT_CONFIG = os.environ.get(CONFIG_ENV) or PACKAGED_CONFIG


def add_config_option(parser: argparse.ArgumentParser, resolve: bool = True) -> None:
    """``--config FILE``; without it ``$HELIOCAL_CONFIG``, else the packaged demo plant
    (:func:`resolve_config` fills it in and says which; with ``resolve=False`` the command
    reads :data:`DEFAULT_CONFIG` itself, only where it needs a plant)."""
    parser.add_argument(
        "--config", default=None, metavar="FILE",
        help=f"plant configuration YAML (default: ${CONFIG_ENV}, else the packaged demo plant)",
    )
    parser.set_defaults(config_resolve=resolve)


def resolve_config(args: argparse.Namespace) -> None:
    """Fill in an omitted ``--config`` of :func:`add_config_option` and say on stderr which
    configuration is used."""
    import sys

    if not getattr(args, "config_resolve", False) or args.config is not None:
        return
    env = os.environ.get(CONFIG_ENV)
    args.config = env or PACKAGED_CONFIG
    args.config_defaulted = True  # a database made with another configuration refuses it (field_prints)
    origin = f"${CONFIG_ENV}" if env else "the packaged demo plant"
    print(f"heliocal: using configuration {args.config} ({origin}; --config FILE to choose)", file=sys.stderr)


def add_json_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays and tuples into JSON-serialisable Python values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def print_json(obj: Any) -> None:
    """Print ``obj`` as one line of JSON (numpy values converted, non-finite floats as null)."""
    print(dumps_json(_plain(obj)))


def existing_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a Path, or raise InputError naming it when it is not a readable file."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} not found: {p}")
    return p


def output_dir(path: str | Path, option: str = "--out") -> Path:
    """Check an output folder before any work: it may exist (as a folder) or be created in an
    existing, writable parent. InputError (exit 2) names the option and the path otherwise;
    nothing is created here."""
    import os

    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise InputError(f"{option} {p}: exists and is not a folder")
        if not os.access(p, os.W_OK | os.X_OK):
            raise InputError(f"{option} {p}: folder is not writable")
        return p
    parent = p.parent
    if not parent.is_dir():
        raise InputError(f"{option} {p}: parent folder {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: cannot create it, {parent} is not writable")
    return p


@contextmanager
def staged_output_dir(path: str | Path, option: str = "--out") -> Iterator[Path]:
    """A temporary folder beside ``path`` to write into; on success its files move into ``path``
    (created, or kept with its other files), on any failure it is removed — so a command that
    stops half-way (a damaged record, Ctrl-C) leaves nothing half-written."""
    import shutil
    import tempfile

    p = output_dir(path, option)
    stage = Path(tempfile.mkdtemp(prefix=f".{p.name}.", dir=p.parent))
    try:
        yield stage
        if not p.exists():
            stage.rename(p)
            return
        for item in sorted(stage.iterdir()):
            target = p / item.name
            if target.is_dir() and item.is_dir():
                shutil.rmtree(target)
            os.replace(item, target)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def output_file(path: str | Path, option: str = "--out") -> Path:
    """Check an output file before any work: its folder exists and is writable, and the path
    is not a folder. InputError (exit 2) names the option and the path; nothing is created."""
    import os

    p = Path(path)
    if p.is_dir():
        raise InputError(f"{option} {p}: is a folder, not a file")
    parent = p.parent
    if not parent.is_dir():
        raise InputError(f"{option} {p}: folder {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise InputError(f"{option} {p}: not writable")
    return p


def check_camera(cfg, args: argparse.Namespace, command: str, needed: bool = True) -> None:
    """Before any work: a command that captures (``needed``) has a camera — ``--simulate`` (the
    simulated plant's), ``--camera-manifest`` (recorded pairs) or the configuration's
    ``camera.driver`` (:func:`controller.devices.factory.open_camera` opens it); InputError
    saying what to give."""
    simulate, manifest = getattr(args, "simulate", False), getattr(args, "camera_manifest", None)
    if simulate and manifest:
        raise InputError("--simulate uses the simulated plant's camera; --camera-manifest cannot be given "
                         "with it")
    if needed and not simulate and not manifest and cfg.camera.driver is None:
        raise InputError(f"{command}: no camera; set camera.driver in the configuration (gige or file, "
                         "docs/camera.md), pass --camera-manifest FILE (recorded pairs) or --simulate "
                         "(the embedded simulated plant)")


def add_field_change_option(parser: argparse.ArgumentParser) -> None:
    """``--accept-field-change`` (:func:`controller.storage.field_prints.check_field`)."""
    parser.add_argument("--accept-field-change", action="store_true",
                        help="use the database's models although the configuration's heliostats or targets "
                             "differ from those they were fitted on (docs/campaigns.md)")


def check_db_field(db: str | Path, cfg, ids: list[str], args: argparse.Namespace) -> None:
    """Before any work, on an existing database: the configuration's field is the one the
    models of ``ids`` were fitted on (:func:`controller.storage.field_prints.check_field`: exit 2
    naming the heliostat and key, unless ``--accept-field-change``, then said on stderr)."""
    from controller.storage.db import open_existing

    p = Path(db)
    if not p.is_file() or p.stat().st_size == 0:
        return  # a new database: no model to apply
    with open_existing(p) as store:
        check_store_field(store, cfg, ids, args)


def check_store_field(store, cfg, ids: list[str], args: argparse.Namespace) -> None:
    """:func:`check_db_field` on an open store; the differences accepted are said on stderr."""
    import sys

    from controller.storage.field_prints import ACCEPT, check_field

    changes = check_field(store, cfg, ids, args.config, accept=args.accept_field_change,
                          defaulted=getattr(args, "config_defaulted", False))
    if changes:
        print(f"heliocal: {ACCEPT}: {len(changes)} difference(s) accepted, e.g. {changes[0]}",
              file=sys.stderr)


def stop_on_signals() -> threading.Event:
    """An event that SIGINT and SIGTERM set: how a serving command (``sim …``) is told to stop,
    so that it cleans up what it created rather than dying."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def serve_until(stop: threading.Event) -> None:
    """Flush what the command printed (its ready line) and wait until ``stop`` is set."""
    sys.stdout.flush()
    while not stop.wait(0.2):
        pass


HIDDEN_ERRORS = ("assumed", "paint-field", "first-light")  # simplant.truth.HIDDEN_ERRORS, not imported


def add_hidden_errors_option(parser: argparse.ArgumentParser) -> None:
    """``--hidden-errors``: how the simulated field is built (simplant's SimulationSettings)."""
    parser.add_argument("--hidden-errors", choices=HIDDEN_ERRORS, default="assumed",
                        help="the simulated field's hidden errors: the simulator's assumptions (default), "
                             "what 16 real Jülich heliostats show (docs/tracking-model.md) or a new field as "
                             "they were before their first calibration (docs/commissioning.md)")


def campaign_heliostats(args, cfg) -> list[str]:
    """The heliostats of ``heliocal campaign run|night``: ``--heliostats`` (ids separated by
    commas, each one of ``cfg``) or every heliostat of ``cfg``; the camera checked for them."""
    from controller.commands._id_lists import split_ids

    ids = [h.id for h in cfg.heliostats]
    if args.heliostats is not None:
        ids = split_ids(args.heliostats, "--heliostats", cfg.heliostat)
    check_camera(cfg, args, f"campaign {args.campaign_command}")
    return ids
