"""``heliocal library build MANIFEST --out LIB.yaml``: build the Hu-moment error library.

MANIFEST is a CSV ``image,label,az_deg,el_deg`` (paths relative to it; further columns such as
``heliostat,source,slant_m,magnitude`` become each entry's ``params``). The library YAML holds
the feature kind (``multi-lobe-hu`` by default: Hu moments at three thresholds and of all the
spot's lobes, whitened by the library's own spread; ``multi-hu`` without the lobes; ``hu`` raw as
in the paper; ``log-hu``; ``blur-hu`` / ``multi-blur-hu``:
moment invariants to a symmetric blur of the whole spot, alone or beside multi-hu), the
normalisation, the unknown threshold calibrated from the library's own spread, and one entry per image. See
docs/recognition.md. ``--json`` prints ``{"library", "entries", "labels", "features",
"unknown_distance"}``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from controller.commands.common import add_json_option, existing_file, output_file, print_json
from controller.commands.devices.beam import add_threshold_option
from controller.errors import InputError
from controller.io.text_numbers import parse_float
from controller.recognition.library import FEATURE_KINDS
from controller.recognition.library_doc import check_widen
from controller.recognition.library_io import build_library_from_manifest, save_library


@contextmanager
def progress(description: str, enabled: bool) -> Iterator[Callable[[int, int], None]]:
    """Yield a ``callback(done, total)``: a rich progress bar on an interactive terminal, else silent."""
    if not (enabled and sys.stderr.isatty()):
        yield lambda done, total: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  transient=True) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


def register(subparsers) -> None:
    p = subparsers.add_parser("library", help="build the Hu-moment error library",
                              description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="library_command", metavar="SUBCOMMAND")
    b = sub.add_parser("build", help="analyse the manifest's images and write LIB.yaml")
    b.add_argument("manifest", metavar="MANIFEST", help="CSV image,label,az_deg,el_deg")
    b.add_argument("--out", required=True, metavar="LIB.yaml", help="library file to write")
    b.add_argument("--features", choices=FEATURE_KINDS, default="multi-lobe-hu",
                   help="multi-lobe-hu = multi-hu and the Hu moments of all lobes above 0.1 of the peak "
                        "(default), multi-hu = raw Hu moments at thresholds 0.1, 0.3, 0.5, hu = raw Hu "
                        "moments at --threshold (the paper's), log-hu = -sign(h) log10|h|, blur-hu = "
                        "invariants to a symmetric blur (whole spot, no threshold), multi-blur-hu = both")
    b.add_argument("--whiten", choices=("auto", "yes", "no"), default="auto",
                   help="compare features after whitening by the library's own spread "
                        "(auto: all but hu and log-hu; 'no' with --features hu is the paper's raw distance)")
    b.add_argument("--widen", default="auto", type=_widen, metavar="auto|no|F[,F...]",
                   help="widened copies (Gaussian σ as a fraction of the spot's d90) tried on a view no "
                        "case claims (auto: 0.1,0.2 for a whitened library, none otherwise)")
    add_threshold_option(b)
    add_json_option(b)
    b.set_defaults(func=run_build)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def _widen(text: str) -> tuple[float, ...] | None:
    """``--widen``: auto -> None (the library's default), no -> none, else σ/d90 fractions in (0, 1]."""
    if text in ("auto", "no"):
        return None if text == "auto" else ()
    try:
        return check_widen([parse_float(v, "--widen") for v in text.split(",")], "--widen")
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, no or numbers like 0.1,0.2, not {text!r}") from None
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_build(args: argparse.Namespace) -> int:
    output_file(args.out)
    manifest = existing_file(args.manifest, "manifest")
    with progress("building library", not args.json) as update:
        lib = build_library_from_manifest(manifest, args.features, args.threshold, progress=update,
                                          whiten={"auto": None, "yes": True, "no": False}[args.whiten],
                                          widen=args.widen)
    save_library(lib, Path(args.out))
    labels = sorted(set(lib.labels))
    if args.json:
        print_json({"library": str(args.out), "entries": len(lib.entries), "labels": labels,
                    "features": lib.features, "unknown_distance": lib.unknown_distance})
    else:
        print(f"{args.out}: {len(lib.entries)} entries, {len(labels)} labels, features {lib.features}, "
              f"unknown beyond {lib.unknown_distance:.4g}")
    return 0
