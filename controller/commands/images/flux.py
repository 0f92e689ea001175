"""``heliocal flux``: irradiance map of a Lambertian target from a sun image (PHLUX).

Contract (docs/flux.md)::

    heliocal flux RECEIVER --sun SUN --dni W_M2 --reflectivity RHO [--ambient AMBIENT]
         [--sun-transmittance T] [--exposure-ratio R] [--sun-angle-mrad 9.3]
         [--distance M --view-angle-deg A] --out FLUX.npy [--png FLUX.png] --json

Double-CCD pairs replace RECEIVER (and AMBIENT) with ``--receiver-pair LOW HIGH
--exposures T_LOW T_HIGH [--ambient-pair LOW HIGH]``; the pair is merged to counts per second,
so the sun exposure must be given (``--sun-exposure T``) instead of ``--exposure-ratio``.

``--crf CRF.yaml`` linearises every image through the camera response (single frames through
its first sensor's, pairs through both in the merge). A receiver with saturated pixels (at the
top code; for pairs, saturated in both) is refused unless ``--allow-saturated``: the flux there
is only a lower bound. ``saturated_px`` in the JSON counts them.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from controller.commands._numbers import (
    DNI,
    EXPOSURE_S,
    PIXELS,
    POSITIVE_RATIO,
    SUN_ANGLE_MRAD,
    Number,
    fraction,
)
from controller.commands.common import add_json_option, existing_file, output_file, print_json
from controller.errors import InputError
from controller.flux import phlux
from controller.flux.sun_disc import SunDiscError, find_sun_disc
from controller.imaging.crf import Crf
from controller.imaging.crf_io import load_crf
from controller.imaging.hdr import HdrMerger, merge_above_offset
from controller.io.images import pyplot, read_image, save_figure, write_float_image

HDR_DARK_OFFSET = 8.0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "flux", help="flux map (W/m²) of a Lambertian target from a sun image (PHLUX)",
        description="Irradiance map of a Lambertian target calibrated by a sun image taken with the "
                    "same camera (Ho & Khalsa 2012). See docs/flux.md.")
    p.add_argument("receiver", nargs="?", metavar="RECEIVER", help="target image (beam on)")
    p.add_argument("--sun", required=True, metavar="SUN", help="sun image, same camera, through an ND filter")
    p.add_argument("--dni", required=True, type=DNI, metavar="W_M2", help="DNI at the sun image, W/m²")
    p.add_argument("--reflectivity", required=True, type=fraction(closed=True), metavar="RHO",
                   help="Lambertian reflectivity of the target (0-1]")
    p.add_argument("--ambient", metavar="AMBIENT", help="same view with the beam off, subtracted")
    p.add_argument("--dark-offset", type=Number(0, 65535), default=0.0, metavar="DN",
                   help="dark level subtracted from RECEIVER when no --ambient is given (default 0)")
    p.add_argument("--sun-transmittance", type=fraction(closed=True), default=1.0, metavar="T",
                   help="ND transmittance in front of the camera for the sun image (default 1)")
    p.add_argument("--receiver-transmittance", type=fraction(closed=True), default=1.0, metavar="T",
                   help="ND transmittance for the receiver image (default 1)")
    p.add_argument("--exposure-ratio", type=POSITIVE_RATIO, default=None, metavar="R",
                   help="(receiver exposure) / (sun exposure) (default 1)")
    p.add_argument("--sun-angle-mrad", type=SUN_ANGLE_MRAD, default=phlux.SUN_ANGLE_RAD * 1e3, metavar="MRAD",
                   help="full angle subtended by the Sun (default 9.3)")
    p.add_argument("--sun-center", type=PIXELS, nargs=2, metavar=("X", "Y"),
                   help="manual sun disc centre, pixels (with --sun-radius)")
    p.add_argument("--sun-radius", type=Number(0, 65535, lo_open=True), metavar="PX",
                   help="manual sun disc radius, pixels")
    p.add_argument("--saturation-level", type=Number(0, 1e12, lo_open=True), metavar="DN",
                   help="sun-image clipping level (default: dtype maximum; needed for float images)")
    p.add_argument("--distance", type=Number(0, 1e5, lo_open=True), metavar="M",
                   help="camera-target distance, m (gives total power)")
    p.add_argument("--view-angle-deg", type=Number(0, 90, hi_open=True), metavar="A",
                   help="angle between target normal and line of sight, degrees (default 0)")
    p.add_argument("--tube-axes-px", type=PIXELS, nargs="+", metavar="X",
                   help="tube panel: x (column) of each tube axis, px; power uses tube surface areas")
    p.add_argument("--tube-radius-px", type=Number(0, 65535, lo_open=True), metavar="R",
                   help="tube panel: tube radius as imaged, px")
    p.add_argument("--known-power-w", type=Number(0, 1e10, lo_open=True), metavar="P",
                   help="beam power on the target (DNI·A·ρ_mirror·cos i, no spillage): adds "
                        "reflectivity_calibrated to the JSON")
    p.add_argument("--receiver-pair", nargs=2, metavar=("LOW", "HIGH"), help="double-CCD receiver pair")
    p.add_argument("--ambient-pair", nargs=2, metavar=("LOW", "HIGH"), help="double-CCD ambient pair")
    p.add_argument("--exposures", type=EXPOSURE_S, nargs=2, metavar=("T_LOW", "T_HIGH"),
                   help="pair exposure times, seconds")
    p.add_argument("--sun-exposure", type=EXPOSURE_S, metavar="S",
                   help="sun exposure time, seconds (with pairs)")
    p.add_argument("--crf", metavar="CRF.yaml",
                   help="camera response: linearise the images (default: linear, I(z) = z)")
    p.add_argument("--allow-saturated", action="store_true",
                   help="accept a receiver with saturated pixels (the flux there is a lower bound)")
    p.add_argument("--hotspots", type=Number(0, 1000, integer=True), default=5, metavar="N",
                   help="number of hot spots listed (default 5)")
    p.add_argument("--out", required=True, metavar="FLUX.npy",
                   help="irradiance map, W/m², float32 (.npy/.tiff)")
    p.add_argument("--png", metavar="FLUX.png", help="false-colour map with colour bar in kW/m²")
    add_json_option(p)
    p.set_defaults(func=run)


def _positive(value: float | None, option: str, upper: float | None = None) -> None:
    if value is None:
        return
    if not (math.isfinite(value) and value > 0) or (upper is not None and value > upper):
        bound = f"in (0, {upper:g}]" if upper is not None else "> 0"
        raise InputError(f"{option} must be {bound}, got {value:g}")


def _check_args(args: argparse.Namespace) -> None:
    _positive(args.dni, "--dni")
    _positive(args.reflectivity, "--reflectivity", 1.0)
    _positive(args.sun_transmittance, "--sun-transmittance", 1.0)
    _positive(args.receiver_transmittance, "--receiver-transmittance", 1.0)
    _positive(args.exposure_ratio, "--exposure-ratio")
    _positive(args.sun_angle_mrad, "--sun-angle-mrad")
    _positive(args.distance, "--distance")
    _positive(args.sun_radius, "--sun-radius")
    _positive(args.sun_exposure, "--sun-exposure")
    if (args.sun_center is None) != (args.sun_radius is None):
        raise InputError("--sun-center and --sun-radius go together")
    if args.view_angle_deg is not None:
        if args.distance is None:
            raise InputError("--view-angle-deg needs --distance")
        if not 0 <= args.view_angle_deg < 90:
            raise InputError(f"--view-angle-deg must be in [0, 90), got {args.view_angle_deg:g}")
    _positive(args.tube_radius_px, "--tube-radius-px")
    _positive(args.known_power_w, "--known-power-w")
    if (args.tube_axes_px is None) != (args.tube_radius_px is None):
        raise InputError("--tube-axes-px and --tube-radius-px go together")
    if (args.tube_axes_px or args.known_power_w) and args.distance is None:
        raise InputError("--tube-axes-px and --known-power-w need --distance")
    if args.tube_axes_px and args.view_angle_deg:
        raise InputError("a tube panel must be viewed along its normal (--view-angle-deg 0)")
    if args.crf and args.dark_offset:
        raise InputError("--dark-offset goes without --crf (the camera response maps the dark level to 0)")
    if args.hotspots < 0:
        raise InputError(f"--hotspots must be >= 0, got {args.hotspots}")
    if args.receiver_pair:
        if args.receiver:
            raise InputError("give RECEIVER or --receiver-pair, not both")
        if not args.exposures or not args.sun_exposure:
            raise InputError("--receiver-pair needs --exposures T_LOW T_HIGH and --sun-exposure S")
        if args.exposure_ratio is not None or args.ambient:
            raise InputError("with --receiver-pair use --ambient-pair, and no --exposure-ratio "
                             "(the merged pair is in counts per second)")
        for t in args.exposures:
            _positive(t, "--exposures")
    elif not args.receiver:
        raise InputError("no receiver image: give RECEIVER or --receiver-pair LOW HIGH")
    elif args.ambient_pair or args.exposures:
        raise InputError("--ambient-pair and --exposures go with --receiver-pair")
    if Path(args.out).suffix.lower() not in (".npy", ".tif", ".tiff"):
        raise InputError(f"--out {args.out}: must end in .npy or .tiff")
    output_file(args.out)
    if args.png and Path(args.png).suffix.lower() != ".png":
        raise InputError(f"--png {args.png}: must end in .png")
    if args.png:
        output_file(args.png, "--png")


def _same_shape(images: dict[str, np.ndarray]) -> None:
    shapes = {name: img.shape for name, img in images.items()}
    if len(set(shapes.values())) > 1:
        listed = ", ".join(f"{name} {s[1]}x{s[0]}" for name, s in shapes.items())
        raise InputError(f"image sizes differ (same camera expected): {listed}")


def _merge_pair(paths: list[str], exposures: tuple[float, float], crf: Crf | None) -> tuple[np.ndarray, int]:
    """Merged pair in counts per second above the dark offset (shape (rows, cols)) and the
    number of its pixels saturated in both images."""
    low, high = (read_image(existing_file(p, "image")) for p in paths)
    _same_shape({paths[0]: low, paths[1]: high})
    try:
        merged = HdrMerger(tuple(exposures), crf, "raised-cosine", HDR_DARK_OFFSET).merge_with_mask(low, high)
        if crf is None:  # I(z) = z keeps the offset, which the fitted response maps to 0
            return merge_above_offset(low, high, tuple(exposures), HDR_DARK_OFFSET), merged.saturated_both
    except InputError as exc:
        raise InputError(f"{paths[0]}, {paths[1]}: {exc}") from None
    return merged.hdr.astype(np.float64), merged.saturated_both


def _linear(img: np.ndarray, crf: Crf | None, name: str) -> np.ndarray:
    """Counts in float64, through the first sensor's inverse response when a CRF is given."""
    if crf is None:
        return img.astype(np.float64)
    top = (1 << crf.bit_depth) - 1
    if not np.issubdtype(img.dtype, np.integer) or img.min() < 0 or img.max() > top:
        raise InputError(f"{name}: --crf needs integer pixels in 0..{top} ({crf.bit_depth}-bit), "
                         f"got {img.dtype} up to {img.max()}")
    return crf.inverse(0)[img]


def _saturated(img: np.ndarray, crf: Crf | None) -> int | None:
    """Pixels at the top code (the CRF's bit depth, else the dtype's); None for float images."""
    if not np.issubdtype(img.dtype, np.integer):
        return None
    top = (1 << crf.bit_depth) - 1 if crf is not None else np.iinfo(img.dtype).max
    return int(np.count_nonzero(img >= top))


def _target_values(args: argparse.Namespace, crf: Crf | None
                   ) -> tuple[np.ndarray, dict[str, np.ndarray], int | None]:
    """Ambient-subtracted target counts, the images to size-check, and the saturated-pixel count."""
    if args.receiver_pair:
        merged, n_sat = _merge_pair(args.receiver_pair, args.exposures, crf)
        shapes = {args.receiver_pair[0]: merged}
        if args.ambient_pair:
            ambient, _ = _merge_pair(args.ambient_pair, args.exposures, crf)
            shapes[args.ambient_pair[0]] = ambient
            _same_shape(shapes)
            merged = merged - ambient
            _beam_left(merged, args.receiver_pair[0], args.ambient_pair[0])
        return merged, shapes, n_sat
    receiver = read_image(existing_file(args.receiver, "receiver image"))
    shapes = {args.receiver: receiver}
    values = _linear(receiver, crf, args.receiver)
    if args.ambient:
        ambient = read_image(existing_file(args.ambient, "ambient image"))
        shapes[args.ambient] = ambient
        _same_shape(shapes)
        values -= _linear(ambient, crf, args.ambient)
        _beam_left(values, args.receiver, args.ambient)
    else:
        values -= args.dark_offset
    return values, shapes, _saturated(receiver, crf)


def _beam_left(values: np.ndarray, receiver: str, ambient: str) -> None:
    """Refuse a receiver no brighter than its ambient: the flux would come out negative."""
    net = float(values.sum())
    if not net > 0:
        raise InputError(f"{receiver}: the ambient {ambient} is as bright or brighter than the receiver "
                         f"(net {net:.4g} counts summed over the image): swapped files, or no beam on")


def _sun_disc(args: argparse.Namespace, sun_path: Path, sun: np.ndarray, crf: Crf | None):
    level = args.saturation_level
    if crf is not None:  # the disc is measured in linear units; so is the clipping level
        top = (1 << crf.bit_depth) - 1
        level = float(crf.inverse(0)[top if level is None else min(max(int(level), 0), top)])
        sun = _linear(sun, crf, str(sun_path))
    try:
        return find_sun_disc(sun, saturation_level=level,
                             center_px=tuple(args.sun_center) if args.sun_center else None,
                             radius_px=args.sun_radius)
    except SunDiscError as exc:
        raise SunDiscError(f"{sun_path}: {exc}") from None


def _write_png(path: str, flux: np.ndarray) -> None:
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=100)
    im = ax.imshow(flux / 1e3, cmap="inferno", origin="upper")
    fig.colorbar(im, ax=ax, label="irradiance, kW/m²")
    ax.set_xlabel("x (column), px")
    ax.set_ylabel("y (row), px")
    ax.set_title(f"PHLUX flux map, peak {flux.max() / 1e3:.1f} kW/m²")
    fig.tight_layout()
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    _check_args(args)
    sun_path = existing_file(args.sun, "sun image")
    sun = read_image(sun_path)
    crf = load_crf(existing_file(args.crf, "CRF file")) if args.crf else None
    values, shapes, n_sat = _target_values(args, crf)
    _same_shape({**shapes, str(sun_path): sun})
    disc = _sun_disc(args, sun_path, sun, crf)
    receiver = args.receiver or f"{args.receiver_pair[0]}, {args.receiver_pair[1]}"
    if n_sat and not args.allow_saturated:
        raise InputError(f"{receiver}: {n_sat} receiver pixels saturated; the flux there would be only a "
                         "lower bound (shorter exposure, a double-CCD pair, or --allow-saturated)")
    gamma = args.sun_angle_mrad * 1e-3
    if args.receiver_pair:
        exposure_ratio = 1.0 / args.sun_exposure
    else:
        exposure_ratio = args.exposure_ratio or 1.0
    flux = phlux.irradiance_from_sun_image(
        values, disc.sum_counts, disc.radius_px, args.dni, args.reflectivity, sun_angle_rad=gamma,
        sun_transmittance=args.sun_transmittance, target_transmittance=args.receiver_transmittance,
        exposure_ratio=exposure_ratio)
    result = {
        "peak_w_m2": float(flux.max()),
        "mean_w_m2": float(flux.mean()),
        "sun_radius_px": disc.radius_px,
        "sun_center_px": [disc.center_px[0], disc.center_px[1]],
        "saturated_px": n_sat,
    }
    if args.distance is not None:
        if args.tube_axes_px:
            area = phlux.tube_panel_area_map(flux.shape, np.asarray(args.tube_axes_px), args.tube_radius_px,
                                             args.distance, disc.radius_px, gamma)
        else:
            area = phlux.pixel_area_m2(args.distance, math.radians(args.view_angle_deg or 0.0),
                                       disc.radius_px, gamma)
        result["total_power_w"] = phlux.total_power_w(flux, area)
        if args.known_power_w:
            result["reflectivity_calibrated"] = phlux.reflectivity_from_known_power(
                result["total_power_w"], args.reflectivity, args.known_power_w)
    result["hotspots"] = [{"x": h.x, "y": h.y, "w_m2": h.w_m2}
                          for h in phlux.find_hotspots(flux, count=args.hotspots)] if args.hotspots else []
    write_float_image(args.out, flux)
    if args.png:
        _write_png(args.png, flux)
    if n_sat:
        print(f"heliocal flux: warning: {receiver}: {n_sat} receiver pixels saturated (allowed); the flux "
              "there is a lower bound", file=sys.stderr)
    if args.json:
        print_json(result)
    else:
        print(f"peak {result['peak_w_m2'] / 1e3:.2f} kW/m², mean {result['mean_w_m2'] / 1e3:.3f} kW/m², "
              f"sun r={disc.radius_px:.2f} px at ({disc.center_px[0]:.2f}, {disc.center_px[1]:.2f})")
        if "total_power_w" in result:
            print(f"total power {result['total_power_w'] / 1e3:.3f} kW")
        print(f"wrote {args.out}" + (f" and {args.png}" if args.png else ""))
    return 0
