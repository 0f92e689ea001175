"""``heliocal sim errorset --out DIR``: render the deterministic error-case test set.

Writes ``DIR/library.csv`` (one nominal view per case, heliostat, source and magnitude),
``DIR/test.csv`` (``--views`` perturbed views per case and test heliostat/source) and
``DIR/images/*.npy`` (merged HDR, float32); both manifests carry the columns
``heliostat,source,slant_m,magnitude`` after ``image,label,az_deg,el_deg``. Held-out splits:
``--test-heliostats``/``--test-sources`` render the test views elsewhere than the library,
``--test-magnitudes LO,HI`` draws each test view's error size from that range. See
:mod:`simplant.errorset` and docs/recognition.md. ``--json`` prints
``{"library_manifest", "test_manifest", "labels", "images"}``.
"""

from __future__ import annotations

import argparse

from controller.commands._id_lists import split_ids
from controller.commands._numbers import SEED, Number
from controller.commands.common import (
    add_config_option,
    add_json_option,
    existing_file,
    output_dir,
    print_json,
)
from controller.commands.images.library import progress
from controller.config import load_config
from controller.errors import InputError
from controller.io.text_numbers import parse_float


def register(subparsers) -> None:
    p = subparsers.add_parser("errorset", help="render error-case library and test manifests",
                              description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=SEED, default=0, metavar="S", help="seed of the perturbations (default 0)")
    p.add_argument("--cases", type=Number(1, 1000, integer=True), default=6, metavar="N",
                   help="number of error cases of the error set, from 1 (default 6)")
    p.add_argument("--combined", action="store_true",
                   help="also every pair of the chosen cases that both change the spot's shape, as cases "
                        "of their own (labels a+b; tracking-offset has no shape and is left out)")
    p.add_argument("--views", type=Number(1, 1000, integer=True), default=14, metavar="N",
                   help="test views per case (default 14)")
    p.add_argument("--heliostat", default="H09", metavar="ID[,ID...]",
                   help="heliostat(s) of the config the library is rendered for (default H09)")
    p.add_argument("--sources", default=None, metavar="ID[,ID...]",
                   help="light source(s) of the library views (default: the calibration's, the lamp)")
    p.add_argument("--magnitudes", default="1", metavar="M[,M...]",
                   help="error sizes of the library entries, multiples of each case's nominal size "
                        "(default 1; e.g. 0.5,1,1.5)")
    p.add_argument("--test-heliostats", default=None, metavar="ID[,ID...]",
                   help="heliostats of the test views (default: the library's)")
    p.add_argument("--test-sources", default=None, metavar="ID[,ID...]",
                   help="light sources of the test views (default: the library's)")
    p.add_argument("--test-magnitudes", default=None, metavar="LO,HI",
                   help="draw each test view's error size uniformly from LO..HI (default: the library's "
                        "magnitudes in turn)")
    add_config_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def _ids(text: str | None, option: str) -> list[str]:
    return [] if text is None else split_ids(text, option, what="id")


def _numbers(text: str, option: str) -> list[float]:
    try:
        vals = [parse_float(t.strip(), option) for t in text.split(",") if t.strip()]
    except InputError:
        raise InputError(f"{option}: not a list of numbers: {text!r}") from None
    if not vals or not all(0 < v <= 10 for v in vals):
        raise InputError(f"{option}: give positive numbers up to 10, got {text!r}")
    return vals


def _scenes(cfg, heliostats: list[str], sources: list[str | None]):
    from simplant.errorset import scene_from_config

    known_h = {h.id for h in cfg.heliostats}
    known_s = {s.id for s in cfg.light_sources}
    for h in heliostats:
        if h not in known_h:
            raise InputError(f"heliostat {h!r}: not in the config (known: {', '.join(sorted(known_h))})")
    for s in sources:
        if s is not None and s not in known_s:
            raise InputError(f"light source {s!r}: not in the config (known: {', '.join(sorted(known_s))})")
    return [scene_from_config(cfg, h, s) for s in sources for h in heliostats]


def run(args: argparse.Namespace) -> int:
    from simplant.errorset import CASES, write_errorset

    if not 1 <= args.cases <= len(CASES):
        raise InputError(f"--cases must be in 1..{len(CASES)}, got {args.cases}")
    if args.views < 1:
        raise InputError(f"--views must be at least 1, got {args.views}")
    magnitudes = _numbers(args.magnitudes, "--magnitudes")
    test_range = None
    if args.test_magnitudes is not None:
        test_range = _numbers(args.test_magnitudes, "--test-magnitudes")
        if len(test_range) != 2 or test_range[0] > test_range[1]:
            raise InputError(f"--test-magnitudes: give LO,HI with LO <= HI, got {args.test_magnitudes!r}")
    heliostats = _ids(args.heliostat, "--heliostat")
    sources = _ids(args.sources, "--sources") or [None]
    output_dir(args.out)
    cfg = load_config(existing_file(args.config, "config"))
    scenes = _scenes(cfg, heliostats, sources)
    test_scenes = None
    if args.test_heliostats is not None or args.test_sources is not None:
        test_scenes = _scenes(cfg, _ids(args.test_heliostats, "--test-heliostats") or heliostats,
                              _ids(args.test_sources, "--test-sources") or sources)
    with progress("rendering error set", not args.json) as update:
        es = write_errorset(args.out, scenes, seed=args.seed, cases=args.cases, views=args.views,
                            progress=update, magnitudes=magnitudes, test_scenes=test_scenes,
                            test_magnitude_range=tuple(test_range) if test_range else None,
                            combined=args.combined)
    if args.json:
        print_json({"library_manifest": str(es.library_manifest), "test_manifest": str(es.test_manifest),
                    "labels": es.labels, "images": es.images})
    else:
        print(f"{es.images} images for {len(es.labels)} cases: {es.library_manifest}, {es.test_manifest}")
    return 0
