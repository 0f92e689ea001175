"""``heliocal capture [--camera gige|file] --config C --out DIR [--json]``: take one frame pair.

Writes ``low.png`` and ``high.png`` (16-bit grey PNG when the pixels have more than 8 bits)
and ``metadata.json`` into DIR: device ids, exposures (s), device timestamps (ns), their
skew (ms), pixel format and ROI. Without ``--camera`` it opens the configuration's
``camera.driver`` as every command does (:func:`controller.devices.factory.open_camera`);
``--camera gige`` opens the GigE Vision imagers of the configuration's ``camera.gige``
section (docs/camera.md); ``--camera file --manifest M`` takes the first pair of a recorded
manifest. ``--json`` prints the metadata as one object. A camera failure exits 1 with one line
naming the imager; nothing is written then.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from controller.commands.common import (
    _plain,
    add_config_option,
    add_json_option,
    existing_file,
    output_dir,
    print_json,
)
from controller.errors import InputError
from controller.io.json_files import dumps_json


def register(subparsers) -> None:
    p = subparsers.add_parser("capture", help="take one frame pair from the camera into a folder",
                              description=__doc__)
    p.add_argument("--camera", choices=("gige", "file"), default=None,
                   help="gige: the configuration's GigE Vision imagers; file: --manifest (default: the "
                        "configuration's camera.driver)")
    p.add_argument("--manifest", metavar="FILE", help="recorded pairs to take the first one from "
                   "(with --camera file)")
    add_config_option(p)
    p.add_argument("--out", required=True, metavar="DIR", help="folder for low.png, high.png, metadata.json")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from controller.config import load_config

    out = output_dir(args.out)
    if args.camera == "file":
        if not args.manifest:
            raise InputError("--camera file: --manifest FILE is required")
        existing_file(args.manifest, "--manifest")
    elif args.manifest:
        raise InputError("--manifest: only with --camera file")
    cfg = load_config(args.config)
    if args.camera == "gige" and cfg.camera.gige is None:
        raise InputError(f"{args.config}: camera.gige: required key is missing for --camera gige "
                         "(docs/camera.md)")
    camera = _open(args, cfg)
    try:
        pair = camera.capture()
    finally:
        camera.close()
    meta = _plain({"camera": args.camera or cfg.camera.driver, "exposures_s": list(pair.exposures),
                   "timestamp_s": pair.timestamp, "shape": list(pair.low.shape), "dtype": str(pair.low.dtype),
                   **pair.metadata})
    _write(out, pair, meta)
    if args.json:
        print_json(meta)
    else:
        skew = f", skew {meta['skew_ms']:.3f} ms" if "skew_ms" in meta else ""
        print(f"captured {pair.low.shape[1]}x{pair.low.shape[0]} {pair.low.dtype} pair, exposures "
              f"{pair.exposures[0]:g}/{pair.exposures[1]:g} s{skew} -> {out}")
    return 0


def _open(args: argparse.Namespace, cfg):
    from controller.devices.factory import open_camera

    if args.camera == "gige":
        return open_camera(cfg.camera.model_copy(update={"driver": "gige"}))
    return open_camera(cfg.camera, args.manifest if args.camera == "file" else None)


def _write(out: Path, pair, meta: dict) -> None:
    import cv2

    from controller.io.images import write_atomic

    out.mkdir(exist_ok=True)
    for name, image in (("low.png", pair.low), ("high.png", pair.high)):
        def writer(tmp: Path, image=image, name=name) -> None:
            if not cv2.imwrite(str(tmp), image):
                raise InputError(f"--out {out}: could not write {name}")
        write_atomic(out / name, writer)
    write_atomic(out / "metadata.json", lambda tmp: tmp.write_text(dumps_json(meta, indent=2) + "\n"))
