"""``heliocal sim errorset --out DIR``: render the deterministic error-case test set.

Writes ``DIR/library.csv`` (one nominal view per case), ``DIR/test.csv`` (``--views``
perturbed views per case) and ``DIR/images/*.npy`` (merged HDR, float32). See
:mod:`simplant.errorset` and docs/recognition.md. ``--json`` prints
``{"library_manifest", "test_manifest", "labels", "images"}``.
"""

from __future__ import annotations

import argparse

from controller.commands._common import (
    add_config_option,
    add_json_option,
    existing_file,
    output_dir,
    print_json,
)
from controller.commands.library import progress
from controller.config import load_config
from controller.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("errorset", help="render error-case library and test manifests",
                              description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the perturbations (default 0)")
    p.add_argument("--cases", type=int, default=6, metavar="N",
                   help="number of error cases of the error set, from 1 (default 6)")
    p.add_argument("--views", type=int, default=14, metavar="N", help="test views per case (default 14)")
    p.add_argument("--heliostat", default="H09", metavar="ID", help="heliostat of the config (default H09)")
    add_config_option(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from simplant.errorset import CASES, scene_from_config, write_errorset

    if not 1 <= args.cases <= len(CASES):
        raise InputError(f"--cases must be in 1..{len(CASES)}, got {args.cases}")
    if args.views < 1:
        raise InputError(f"--views must be at least 1, got {args.views}")
    output_dir(args.out)
    cfg = load_config(existing_file(args.config, "config"))
    scene = scene_from_config(cfg, args.heliostat)
    with progress("rendering error set", not args.json) as update:
        es = write_errorset(args.out, scene, seed=args.seed, cases=args.cases, views=args.views,
                            progress=update)
    if args.json:
        print_json({"library_manifest": str(es.library_manifest), "test_manifest": str(es.test_manifest),
                    "labels": es.labels, "images": es.images})
    else:
        print(f"{es.images} images for {len(es.labels)} cases: {es.library_manifest}, {es.test_manifest}")
    return 0
