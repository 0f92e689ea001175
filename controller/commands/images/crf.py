"""``heliocal crf fit``: fit the camera response of both sensors from integrating-sphere data.

Contract::

    heliocal crf fit DATA.csv --out crf.yaml [--bit-depth 8] [--json]

DATA.csv has columns ``sensor,exposure_value,pixel_mean`` (exposure value = exposure time ×
irradiance); the first sensor named in the file is the LOW one. Saturated points are ignored.
``--json`` prints ``{"out": path, "sensors": [{"name", "uncertainty_pct", "points_used",
"points_saturated", "dark_level"}, ...]}``.
"""

from __future__ import annotations

import numpy as np

from controller.commands._numbers import Number
from controller.commands.common import add_json_option, existing_file, output_file, print_json
from controller.errors import InputError
from controller.imaging.crf_io import fit_crf_file, read_sphere_csv, save_crf


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
    f.add_argument("--bit-depth", type=Number(8, 16, integer=True), default=8,
                   help="sensor bit depth (default 8)")
    f.add_argument("--plot", metavar="PNG", default=None,
                   help="plot of the fitted responses against the data (default: beside --out, .png)")
    add_json_option(f)
    f.set_defaults(func=run_fit)
    p.set_defaults(func=lambda args: p.print_help() or 2)


def run_fit(args) -> int:
    if not 1 <= args.bit_depth <= 16:
        raise InputError(f"--bit-depth must be in 1..16, got {args.bit_depth}")
    out = output_file(args.out)
    plot = output_file(args.plot or out.with_suffix(".png"), "--plot")
    data = existing_file(args.data, "CRF data CSV")
    crf, fits = fit_crf_file(data, args.bit_depth)
    save_crf(crf, out)
    _plot_fit(plot, crf, read_sphere_csv(data))
    rows = [{"name": f.sensor.name, "uncertainty_pct": f.uncertainty_pct, "points_used": f.points_used,
             "points_saturated": f.points_saturated, "dark_level": f.dark_level} for f in fits]
    if args.json:
        print_json({"out": str(args.out), "plot": str(plot), "sensors": rows})
    else:
        for r in rows:
            print(f"{r['name']}: fit uncertainty ±{r['uncertainty_pct']:.2f} % (1σ), {r['points_used']} "
                  f"points used, {r['points_saturated']} saturated ignored, dark level {r['dark_level']:.2f}")
        print(f"wrote {args.out} and {plot}")
    return 0


def _plot_fit(path, crf, samples: dict) -> None:
    """Each sensor's fitted response z(X) (the inverse of the tabulated I(z)) over its data."""
    from controller.io.images import pyplot, save_figure

    plt = pyplot()

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for sensor, (x, z) in zip(crf.sensors, samples.values(), strict=True):
        levels = np.arange(len(sensor.inverse_response))
        line, = ax.plot(sensor.inverse_response, levels, lw=1.5, label=f"{sensor.name} fit")
        ax.plot(x, z, ".", ms=4, color=line.get_color(), alpha=0.6, label=f"{sensor.name} data")
    ax.set_xlabel("exposure value X (exposure time × irradiance, linear units)")
    ax.set_ylabel("pixel value z (counts)")
    ax.set_title("Camera response: fit against integrating-sphere data")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path, dpi=110, bbox_inches="tight")
