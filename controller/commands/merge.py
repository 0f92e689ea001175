"""``heliocal merge``: HDR merge of one double-CCD pair by Eq. (1) (docs/imaging.md).

Contract::

    heliocal merge LOW.png HIGH.png --exposures 0.010 0.020 [--crf crf.yaml]
          [--weighting raised-cosine] [--dark-offset 8] --out HDR.npy [--json]

``--out`` ends in ``.npy`` (float32) or ``.tiff``/``.tif`` (32-bit float), written atomically.
``--json`` prints ``{"shape": [h, w], "min", "max", "saturated_both", "dark_both"}``.
"""

from __future__ import annotations

import sys

import numpy as np

from controller.commands._numbers import EXPOSURE_S, Number
from controller.commands.common import add_json_option, existing_file, output_file, print_json
from controller.errors import InputError
from controller.imaging.crf_io import load_crf
from controller.imaging.hdr import HdrMerger, pair_bit_depth
from controller.imaging.weights import NAMES
from controller.io.images import read_image, write_float_image, write_preview


def register(subparsers) -> None:
    p = subparsers.add_parser("merge", help="merge a LOW/HIGH double-CCD pair into one HDR image",
                              description="HDR merge of a double-CCD pair (Eq. (1), known response).")
    p.add_argument("low", metavar="LOW", help="shorter exposure image (8/16-bit PNG/TIFF or .npy)")
    p.add_argument("high", metavar="HIGH", help="longer exposure image, same size")
    p.add_argument("--exposures", nargs=2, type=EXPOSURE_S, required=True, metavar=("T_LOW", "T_HIGH"),
                   help="exposure times in seconds, LOW first")
    p.add_argument("--crf", metavar="CRF.yaml", help="camera response file (default: linear I(z) = z)")
    p.add_argument("--weighting", default="raised-cosine", choices=NAMES, help="weighting function")
    p.add_argument("--dark-offset", type=Number(0, 65535), default=8.0, metavar="COUNTS",
                   help="dark-signal offset in counts (default 8)")
    p.add_argument("--out", required=True, metavar="HDR.npy", help="output .npy or .tiff (32-bit float)")
    add_json_option(p)
    p.set_defaults(func=run)


# Above this fraction of unsaturated pixels brighter in LOW than in HIGH the pair is refused:
# the shorter exposure can never be brighter, so a swapped pair (or two unrelated images) shows
# it almost everywhere; a few such pixels (noise, a flicker between the sensors) only warn.
MAX_INCONSISTENT = 0.5
INCONSISTENT_MARGIN = 4  # counts of noise allowed before a pixel counts as inconsistent


def inconsistent_fraction(low: np.ndarray, high: np.ndarray, z_max: int) -> float:
    """Fraction of the lit pixels, unsaturated in both, where LOW exceeds HIGH by more than the
    noise. Lit: above the darkest pixel of the pair by twice the noise margin (the background
    says nothing about which image is which)."""
    lo, hi = low.astype(np.int64), high.astype(np.int64)
    floor = min(int(lo.min()), int(hi.min())) + 2 * INCONSISTENT_MARGIN
    usable = (lo < z_max) & (hi < z_max) & (np.maximum(lo, hi) > floor)
    n = int(np.count_nonzero(usable))
    return float(np.count_nonzero(usable & (lo > hi + INCONSISTENT_MARGIN)) / n) if n else 0.0


def run(args) -> int:
    out = output_file(args.out)
    if out.suffix.lower() not in (".npy", ".tif", ".tiff"):
        raise InputError(f"--out {out}: must end in .npy or .tiff")
    preview = output_file(out.with_suffix(".png"), "--out (its .png preview)")
    low = read_image(existing_file(args.low, "LOW image"))
    high = read_image(existing_file(args.high, "HIGH image"))
    crf = load_crf(existing_file(args.crf, "CRF file")) if args.crf else None
    if crf is None and low.dtype != high.dtype:
        raise InputError(f"{args.low} is {low.dtype}, {args.high} is {high.dtype}: the two sensors of one "
                         "camera deliver one pixel format; give --crf (it states the sensors' bit depth)")
    merger = HdrMerger(tuple(args.exposures), crf, args.weighting, args.dark_offset,
                       bit_depth=pair_bit_depth(low, high, crf))
    try:
        result = merger.merge_with_mask(low, high)
    except InputError as exc:
        raise InputError(f"{args.low}, {args.high}: {exc}") from None
    bad = inconsistent_fraction(low, high, (1 << merger.bit_depth) - 1)
    if bad > MAX_INCONSISTENT:
        raise InputError(f"{args.low}, {args.high}: {100 * bad:.1f} % of the lit pixels are brighter in LOW "
                         "than in HIGH: swapped or not one pair (LOW is the shorter exposure)")
    if bad > 0.001:
        print(f"heliocal merge: warning: {100 * bad:.2f} % of the lit pixels are brighter in LOW than "
              "in HIGH",
              file=sys.stderr)
    write_float_image(out, result.hdr)
    write_preview(preview, result.hdr)
    info = {"shape": list(result.hdr.shape), "min": float(result.hdr.min()), "max": float(result.hdr.max()),
            "saturated_both": result.saturated_both, "saturated_px": result.saturated_both,
            "dark_both": result.dark_both, "inconsistent_fraction": bad, "preview": str(preview)}
    if args.json:
        print_json(info)
    else:
        print(f"wrote {out}: {info['shape'][1]}x{info['shape'][0]}, min {info['min']:.6g}, "
              f"max {info['max']:.6g}, saturated in both {info['saturated_both']}, "
              f"dark in both {info['dark_both']}")
    return 0
