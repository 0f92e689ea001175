"""``heliocal beam IMAGE``: beam-spot analysis (centroid, peak, total, ellipse, d90, Hu moments).

JSON (``--json``): ``{"centroid_px": [x, y], "peak", "total", "pixels", "hu": [7],
"ellipse": {"major_px", "minor_px", "angle_deg"}, "d90_px", "saturated_px"}``; x = column,
y = row, (0, 0) the centre of the top-left pixel. With ``--background fit`` also
``"spot_fit": {"centre_px", "amplitude", "sigma_major_px", "sigma_minor_px", "angle_deg",
"exponent", "residual_rms"}``. ``--plot DIR`` writes one PNG per intermediate step.

Every answer says whether there is a beam (``"beam"``, ``"statistic"``, ``"statistic_name"``,
``"threshold"``; :mod:`controller.imaging.presence`), and where the spot runs out of the view
(``"clipped"``: edges) or a second spot is in view (``"second_spot_px"``: [x, y] or null).
No beam: exit status 4, JSON ``{"beam": false, "statistic", "statistic_name", "threshold",
"reason"}`` (one line on stdout without ``--json``); nothing else is computed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from controller.commands._numbers import fraction
from controller.commands.common import add_json_option, existing_file, output_dir, print_json
from controller.errors import InputError, NoBeamError
from controller.imaging.beam import BeamResult, analyze
from controller.io.images import pyplot, read_image, save_figure


def add_threshold_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--threshold", type=fraction(), default=0.5, metavar="F",
                        help="segmentation threshold as a fraction of the peak (default 0.5)")


def register(subparsers) -> None:
    p = subparsers.add_parser("beam", help="analyse a beam spot image",
                              description=__doc__.splitlines()[0])
    p.add_argument("image", metavar="IMAGE", help="8/16-bit grey PNG/TIFF, float .npy/.tiff")
    add_threshold_option(p)
    p.add_argument("--background", default="auto", metavar="auto|local|fit|none|FILE",
                   help="background: auto (sigma-clipped plane), local (plane refitted to a ring around "
                        "the spot), fit (spot model + background surface, robust least squares; the "
                        "centroid is the model centre), none, or a null image (default auto)")
    p.add_argument("--mask", metavar="FILE", help="target mask image (non-zero = on target)")
    p.add_argument("--plot", metavar="DIR", help="write the intermediate steps as PNGs into DIR")
    add_json_option(p)
    p.set_defaults(func=run)


def saturated_px(image: np.ndarray) -> int | None:
    """Pixels at the image's top code (integer images; None for float HDR, whose clipping the
    merge reports). A flat-topped core biases the centroid and breaks the Hu moments."""
    if not np.issubdtype(image.dtype, np.integer):
        return None
    return int(np.count_nonzero(image == np.iinfo(image.dtype).max))


def run(args: argparse.Namespace) -> int:
    if args.plot:
        output_dir(args.plot, "--plot")
    image = read_image(existing_file(args.image, "image"))
    if image.size and float(image.max()) < 0:  # (all zeros is analyze's own message)
        raise InputError(f"{args.image}: no positive signal (maximum {float(image.max()):g}): a beam image "
                         "has counts above zero; is it negated or background-subtracted twice?")
    background = args.background
    if background not in ("auto", "local", "fit", "none"):
        background = read_image(existing_file(background, "background image"))
    mask = read_image(existing_file(args.mask, "mask image")) if args.mask else None
    try:
        result = analyze(image, threshold=args.threshold, background=background, mask=mask,
                         keep_steps=bool(args.plot))
    except NoBeamError as exc:
        return no_beam(args, exc)
    except InputError as exc:
        raise InputError(f"{args.image}: {exc}") from None  # e.g. "image is all zeros"
    if args.plot:
        plot_steps(result, Path(args.plot))
    sat = saturated_px(image)
    if sat:
        print(f"heliocal beam: warning: {args.image}: {sat} pixels saturated at the top code; the "
              "centroid and shape of a clipped core are biased (shorter exposure or the HDR pair)",
              file=sys.stderr)
    if args.json:
        print_json({**result.as_dict(), "saturated_px": sat})
    else:
        d = result.as_dict()
        print(f"centroid (x, y) = ({d['centroid_px'][0]:.3f}, {d['centroid_px'][1]:.3f}) px, "
              f"peak {d['peak']:.4g}, total {d['total']:.4g}, {d['pixels']} px")
        e = d["ellipse"]
        print(f"ellipse {e['major_px']:.2f} x {e['minor_px']:.2f} px at {e['angle_deg']:.1f} deg, "
              f"d90 {d['d90_px']:.2f} px")
        print("hu " + " ".join(f"{v:.6g}" for v in d["hu"]))
    return 0


def no_beam(args: argparse.Namespace, exc: NoBeamError) -> int:
    """The "no beam" answer of ``beam`` and ``match``: JSON or one line on stdout, exit 4."""
    if args.json:
        print_json({**exc.detail, "reason": str(exc)})
    else:
        print(f"{args.image}: {exc}")
    return NoBeamError.exit_code


def plot_steps(result: BeamResult, out: Path) -> list[Path]:
    """One PNG per step of the chain (input, background, subtracted, mask, threshold, spot with
    centroid, ellipse and d90 circle). Written atomically; returns the paths."""
    plt = pyplot()
    from matplotlib.patches import Circle
    from matplotlib.patches import Ellipse as EllipsePatch

    if not result.steps:
        raise InputError("no intermediate steps kept; call analyze(..., keep_steps=True)")
    out.mkdir(parents=True, exist_ok=True)
    titles = {
        "input": "1 input", "background": "2 background model", "subtracted": "3 background subtracted",
        "mask": "4 target mask", "threshold": f"5 above threshold ({result.threshold_level:.4g})",
        "spot": "6 segmented spot, centroid, ellipse, d90",
    }
    paths = []
    for i, (key, title) in enumerate(titles.items(), start=1):
        img = np.asarray(result.steps[key], dtype=float)
        fig, ax = plt.subplots(figsize=(6, 5))
        im = ax.imshow(img, cmap="inferno" if key != "mask" else "gray", interpolation="nearest")
        fig.colorbar(im, ax=ax, shrink=0.8)
        if key == "spot":
            cx, cy = result.centroid_px
            ax.plot([cx], [cy], "c+", ms=14, mew=2)
            e = result.ellipse
            ax.add_patch(EllipsePatch((cx, cy), e.major_px, e.minor_px, angle=e.angle_deg, fill=False,
                                      ec="cyan", lw=1.2))
            ax.add_patch(Circle((cx, cy), result.d90_px / 2, fill=False, ec="lime", ls="--", lw=1.2))
        ax.set_title(title)
        ax.set_xlabel("x (column) px")
        ax.set_ylabel("y (row) px")
        path = out / f"{i}-{key}.png"
        save_figure(fig, path, dpi=100)
        paths.append(path)
    return paths
