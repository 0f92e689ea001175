"""``heliocal match IMAGE --library LIB.yaml``: recognise a beam image's error case.

JSON (``--json``): ``{"label", "distance", "runner_up": {"label", "distance"}, "az_deg",
"el_deg", "unknown": false, "nearest", "error_deg", "coarse_correction_deg", "magnitude",
"confidence"}``, plus ``"correction"`` when the entry has one. ``az_deg``/``el_deg`` are the
nearest entry's; ``error_deg`` is the beam pointing error (Δaz, Δel, degrees) interpolated over
the nearest entries of the case, ``coarse_correction_deg`` its negative, ``magnitude`` the
interpolated error size, ``confidence`` in [0, 1]. When the image is farther than the library's
unknown threshold from every entry, ``label`` is ``"unknown"``, ``unknown`` is true,
az/el/correction/estimates are null, confidence 0, and ``nearest`` names the closest case.

An image without a beam (:mod:`controller.imaging.presence`) is not matched: exit status 4 and
``{"beam": false, "statistic", "statistic_name", "threshold", "reason"}`` as ``heliocal beam``.
"""

from __future__ import annotations

import argparse

from controller.commands.common import add_json_option, existing_file, print_json
from controller.commands.devices.beam import no_beam
from controller.errors import InputError, NoBeamError
from controller.imaging.beam import check_image
from controller.imaging.presence import detect_beam
from controller.io.images import read_image
from controller.recognition.confusion import mechanisms
from controller.recognition.library import Library
from controller.recognition.library_io import load_library


def register(subparsers) -> None:
    p = subparsers.add_parser("match", help="match a beam image against the error library",
                              description=__doc__.splitlines()[0])
    p.add_argument("image", metavar="IMAGE", help="beam image (HDR .npy/.tiff or grey PNG/TIFF)")
    p.add_argument("--library", required=True, metavar="LIB.yaml",
                   help="library from 'heliocal library build'")
    add_json_option(p)
    p.set_defaults(func=run)


def match_image(lib: Library, image) -> dict:
    """Analyse ``image`` with the library's threshold and match it; returns the JSON contract."""
    m = lib.match_image(image)
    entry = lib.entries[m.index]
    sizeless = m.unknown or m.widened > 0  # a widened match names the case, not its size
    out = {
        "label": "unknown" if m.unknown else m.label,
        "distance": m.distance,
        "runner_up": {"label": m.runner_up, "distance": m.runner_up_distance},
        "az_deg": None if sizeless else entry.az_deg,
        "el_deg": None if sizeless else entry.el_deg,
        "unknown": m.unknown,
        "nearest": m.label,
        "error_deg": list(m.error_deg) if m.error_deg else None,
        "coarse_correction_deg": list(m.coarse_correction_deg) if m.coarse_correction_deg else None,
        "magnitude": m.magnitude,
        "confidence": m.confidence,
        "widened": m.widened,
        "mechanisms": list(mechanisms("unknown" if m.unknown else m.label)),
    }
    if entry.correction is not None:
        out["correction"] = None if sizeless else entry.correction
    return out


def run(args: argparse.Namespace) -> int:
    lib = load_library(existing_file(args.library, "library"))
    image = read_image(existing_file(args.image, "image"))
    try:
        presence = detect_beam(check_image(image))
        if not presence.beam:
            return no_beam(args, NoBeamError(f"no beam: {presence.reason()}", presence.as_dict()))
        result = match_image(lib, image)
    except InputError as exc:
        raise InputError(f"{args.image}: {exc}") from None  # e.g. "image is all zeros"
    if args.json:
        print_json(result)
    else:
        ru = result["runner_up"]
        ru_txt = f"{ru['label']} at {ru['distance']:.4g}" if ru["label"] else "none"
        widened = f"; widened σ = {result['widened']:g} × d90, no size" if result["widened"] else ""
        print(f"{result['label']} (distance {result['distance']:.4g}; runner-up {ru_txt}{widened})")
    return 0
