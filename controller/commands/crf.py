"""``heliocal crf fit``: fit the camera response of both sensors from integrating-sphere data.

Contract::

    heliocal crf fit DATA.csv --out crf.yaml [--bit-depth 8] [--json]

DATA.csv has columns ``sensor,exposure_value,pixel_mean`` (exposure value = exposure time ×
irradiance); the first sensor named in the file is the LOW one. Saturated points are ignored.
``--json`` prints ``{"out": path, "sensors": [{"name", "uncertainty_pct", "points_used",
"points_saturated", "dark_level"}, ...]}``.
"""

from __future__ import annotations

from controller.commands._common import add_json_option, existing_file, print_json
from controller.errors import InputError
from controller.imaging.crf_io import fit_crf_file, save_crf


def register(subparsers) -> None:
    p = subparsers.add_parser("crf", help="camera response (CRF) calibration",
                              description="Camera response function tools.")
    sub = p.add_subparsers(dest="crf_command", metavar="SUBCOMMAND")
    f = sub.add_parser("fit", help="fit a monotone response per sensor from integrating-sphere data",
                       description="Fit a monotone response per sensor from a CSV with columns "
                                   "sensor,exposure_value,pixel_mean and write the CRF YAML.")
    f.add_argument("data", metavar="DATA.csv",
                   help="integrating-sphere data: CSV with columns sensor,exposure_value,pixel_mean")
    f.add_argument("--out", required=True, metavar="crf.yaml", help="CRF file to write (YAML)")
    f.add_argument("--bit-depth", type=int, default=8, help="sensor bit depth (default 8)")
    add_json_option(f)
    f.set_defaults(func=run_fit)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def run_fit(args) -> int:
    if not 1 <= args.bit_depth <= 16:
        raise InputError(f"--bit-depth must be in 1..16, got {args.bit_depth}")
    crf, fits = fit_crf_file(existing_file(args.data, "CRF data CSV"), args.bit_depth)
    save_crf(crf, args.out)
    rows = [{"name": f.sensor.name, "uncertainty_pct": f.uncertainty_pct, "points_used": f.points_used,
             "points_saturated": f.points_saturated, "dark_level": f.dark_level} for f in fits]
    if args.json:
        print_json({"out": str(args.out), "sensors": rows})
    else:
        for r in rows:
            print(f"{r['name']}: fit uncertainty ±{r['uncertainty_pct']:.2f} % (1σ), {r['points_used']} "
                  f"points used, {r['points_saturated']} saturated ignored, dark level {r['dark_level']:.2f}")
        print(f"wrote {args.out}")
    return 0
