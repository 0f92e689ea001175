"""``heliocal merge``: HDR merge of one double-CCD pair by Eq. (1) (docs/imaging.md).

Contract::

    heliocal merge LOW.png HIGH.png --exposures 0.010 0.020 [--crf crf.yaml]
          [--weighting raised-cosine] [--dark-offset 8] --out HDR.npy [--json]

``--out`` ends in ``.npy`` (float32) or ``.tiff``/``.tif`` (32-bit float), written atomically.
``--json`` prints ``{"shape": [h, w], "min", "max", "saturated_both", "dark_both"}``.
"""

from __future__ import annotations

from pathlib import Path

from controller.commands._common import add_json_option, existing_file, print_json
from controller.errors import InputError
from controller.imaging.crf_io import load_crf
from controller.imaging.hdr import HdrMerger, pair_bit_depth
from controller.imaging.weights import NAMES
from controller.io.images import read_image, write_float_image


def register(subparsers) -> None:
    p = subparsers.add_parser("merge", help="merge a LOW/HIGH double-CCD pair into one HDR image",
                              description="HDR merge of a double-CCD pair (Eq. (1), known response).")
    p.add_argument("low", metavar="LOW", help="shorter exposure image (8/16-bit PNG/TIFF or .npy)")
    p.add_argument("high", metavar="HIGH", help="longer exposure image, same size")
    p.add_argument("--exposures", nargs=2, type=float, required=True, metavar=("T_LOW", "T_HIGH"),
                   help="exposure times in seconds, LOW first")
    p.add_argument("--crf", metavar="CRF.yaml", help="camera response file (default: linear I(z) = z)")
    p.add_argument("--weighting", default="raised-cosine", choices=NAMES, help="weighting function")
    p.add_argument("--dark-offset", type=float, default=8.0, metavar="COUNTS",
                   help="dark-signal offset in counts (default 8)")
    p.add_argument("--out", required=True, metavar="HDR.npy", help="output .npy or .tiff (32-bit float)")
    add_json_option(p)
    p.set_defaults(func=run)


def run(args) -> int:
    out = Path(args.out)
    if out.suffix.lower() not in (".npy", ".tif", ".tiff"):
        raise InputError(f"--out {out}: must end in .npy or .tiff")
    low = read_image(existing_file(args.low, "LOW image"))
    high = read_image(existing_file(args.high, "HIGH image"))
    crf = load_crf(existing_file(args.crf, "CRF file")) if args.crf else None
    merger = HdrMerger(tuple(args.exposures), crf, args.weighting, args.dark_offset,
                       bit_depth=pair_bit_depth(low, high, crf))
    try:
        result = merger.merge_with_mask(low, high)
    except InputError as exc:
        raise InputError(f"{args.low}, {args.high}: {exc}") from None
    write_float_image(out, result.hdr)
    info = {"shape": list(result.hdr.shape), "min": float(result.hdr.min()), "max": float(result.hdr.max()),
            "saturated_both": result.saturated_both, "dark_both": result.dark_both}
    if args.json:
        print_json(info)
    else:
        print(f"wrote {out}: {info['shape'][1]}x{info['shape'][0]}, min {info['min']:.6g}, "
              f"max {info['max']:.6g}, saturated in both {info['saturated_both']}, "
              f"dark in both {info['dark_both']}")
    return 0
