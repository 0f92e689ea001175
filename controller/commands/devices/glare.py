"""``heliocal glare``: ocular hazard (retinal irradiance and zone) of a glint or glare source.

Contract (docs/glare.md)::

    heliocal glare --corneal-irradiance-w-m2 E --subtended-angle-mrad W --json
    heliocal glare --sun SUN --source IMAGE --dni W_M2 [--sun-transmittance T] --json

both print ``{"retinal_irradiance_w_cm2", "subtended_angle_mrad", "zone"}``. The geometry mode
``--geometry heliostat|trough|receiver ... --distance-range MIN MAX`` prints the curve against
distance. ``--png`` draws the hazard plot.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict

import numpy as np

from controller.commands._numbers import DNI, POSITIVE_RATIO, SUN_ANGLE_MRAD, Number, fraction
from controller.commands.common import add_json_option, existing_file, output_file, print_json
from controller.errors import InputError
from controller.flux import glare
from controller.flux.phlux import SUN_ANGLE_RAD
from controller.flux.sun_disc import SunDiscError, find_sun_disc, saturation_level_for
from controller.io.images import pyplot, read_image, save_figure

ZONE_COLOURS = {"green": "#4caf50", "yellow": "#ffc107", "red": "#e53935"}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "glare", help="ocular hazard of a glare source (retinal irradiance, green/yellow/red)",
        description="Retinal irradiance and hazard zone (Ho, Ghanbari & Diver 2011; SGHAT) from a "
                    "corneal irradiance, from a sun image and a source image, or from geometry. "
                    "See docs/glare.md.")
    m = p.add_argument_group("direct")
    m.add_argument("--corneal-irradiance-w-m2", type=Number(0, 1e6, lo_open=True), metavar="E",
                   help="corneal irradiance, W/m²")
    m.add_argument("--subtended-angle-mrad", type=Number(0, 1000, lo_open=True), metavar="W",
                   help="source angle, mrad")
    i = p.add_argument_group("from images (same camera)")
    i.add_argument("--sun", metavar="SUN", help="sun image through an ND filter")
    i.add_argument("--source", metavar="IMAGE", help="image of the glare source")
    i.add_argument("--sun-transmittance", type=fraction(closed=True), default=1.0, metavar="T",
                   help="ND transmittance for the sun image (default 1)")
    i.add_argument("--source-transmittance", type=fraction(closed=True), default=1.0, metavar="T",
                   help="ND transmittance for the source image (default 1)")
    i.add_argument("--exposure-ratio", type=POSITIVE_RATIO, default=1.0, metavar="R",
                   help="(source exposure) / (sun exposure) (default 1)")
    i.add_argument("--threshold-fraction", type=fraction(), default=0.1, metavar="F",
                   help="source region: pixels above background + F·(peak - background) (default 0.1)")
    g = p.add_argument_group("from geometry")
    g.add_argument("--geometry", choices=("heliostat", "trough", "receiver"),
                   help="specular heliostat beam, trough beam, or diffuse receiver")
    g.add_argument("--distance-range", type=Number(0, 1e6, lo_open=True), nargs=2, metavar=("MIN", "MAX"),
                   help="distances from the source, m")
    g.add_argument("--points", type=Number(2, 100_000, integer=True), default=200, metavar="N",
                   help="log-spaced distances (default 200)")
    g.add_argument("--mirror-area-m2", type=Number(0, 1e4, lo_open=True), metavar="A",
                   help="heliostat area A_h, m²")
    g.add_argument("--aperture-width-m", type=Number(0, 100, lo_open=True), metavar="W",
                   help="trough aperture width W_h, m")
    g.add_argument("--focal-length-m", type=Number(0, 1e6, lo_open=True, infinite=True),
                   default=math.inf, metavar="F",
                   help="focal length, m (default: flat mirror)")
    g.add_argument("--slope-error-mrad", type=Number(0, 100), default=2.0, metavar="S",
                   help="mirror slope error, mrad RMS (default 2)")
    g.add_argument("--reflectivity", type=fraction(closed=True), default=0.9, metavar="RHO",
                   help="mirror reflectivity (default 0.9)")
    g.add_argument("--reflected-power-w", type=Number(0, 1e10, lo_open=True), metavar="P",
                   help="receiver: diffusely reflected power P_d, W")
    g.add_argument("--reflecting-area-m2", type=Number(0, 1e6, lo_open=True), metavar="A",
                   help="receiver: reflecting area A_d, m²")
    g.add_argument("--seen-area-m2", type=Number(0, 1e6, lo_open=True), metavar="A",
                   help="receiver: area seen by the observer A_s, m²")
    g.add_argument("--view-angle-deg", type=Number(0, 90, hi_open=True), default=0.0, metavar="A",
                   help="receiver: angle between its normal and the observer, degrees (default 0)")
    p.add_argument("--dni", type=DNI, metavar="W_M2", help="direct normal irradiance, W/m²")
    p.add_argument("--sun-angle-mrad", type=SUN_ANGLE_MRAD, default=SUN_ANGLE_RAD * 1e3, metavar="MRAD",
                   help="full angle subtended by the Sun (default 9.3)")
    e = p.add_argument_group("eye and thresholds")
    e.add_argument("--pupil-diameter-mm", type=Number(0, 10, lo_open=True), default=2.0,
                   help="pupil diameter (default 2)")
    e.add_argument("--eye-focal-length-mm", type=Number(0, 50, lo_open=True), default=17.0,
                   help="eye focal length (default 17)")
    e.add_argument("--ocular-transmittance", type=fraction(closed=True), default=0.5,
                   help="ocular transmittance (default 0.5)")
    defaults = glare.HazardThresholds()
    e.add_argument("--burn-coefficient", type=Number(0, 1e3, lo_open=True), default=defaults.burn_coefficient,
                   help=f"retinal burn threshold C in C·ω^-n W/cm² (default {defaults.burn_coefficient})")
    e.add_argument("--burn-exponent", type=Number(0, 10, lo_open=True), default=defaults.burn_exponent,
                   help=f"retinal burn threshold n (default {defaults.burn_exponent})")
    e.add_argument("--afterimage-coefficient", type=Number(0, 1, lo_open=True),
                   default=defaults.afterimage_coefficient,
                   help=f"after-image threshold C (default {defaults.afterimage_coefficient})")
    e.add_argument("--afterimage-exponent", type=Number(0, 10, lo_open=True),
                   default=defaults.afterimage_exponent,
                   help=f"after-image threshold n (default {defaults.afterimage_exponent})")
    p.add_argument("--png", metavar="PLOT.png", help="draw the hazard plot")
    add_json_option(p)
    p.set_defaults(func=run)


def _require_positive(args: argparse.Namespace, *names: str) -> None:
    for name in names:
        value = getattr(args, name)
        option = "--" + name.replace("_", "-")
        if value is None:
            raise InputError(f"{option} is required in this mode")
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{option} must be > 0, got {value:g}")


def _mode(args: argparse.Namespace) -> str:
    direct = args.corneal_irradiance_w_m2 is not None or args.subtended_angle_mrad is not None
    image = args.sun is not None or args.source is not None
    modes = [name for name, on in (("direct", direct), ("image", image), ("geometry", args.geometry)) if on]
    if len(modes) != 1:
        raise InputError("give exactly one of: --corneal-irradiance-w-m2/--subtended-angle-mrad, "
                         "--sun/--source, or --geometry" + (f" (got {', '.join(modes)})" if modes else ""))
    return modes[0]


def _eye_and_thresholds(args: argparse.Namespace) -> tuple[glare.EyeModel, glare.HazardThresholds]:
    _require_positive(args, "pupil_diameter_mm", "eye_focal_length_mm", "ocular_transmittance",
                      "burn_coefficient", "burn_exponent", "afterimage_coefficient", "afterimage_exponent",
                      "sun_angle_mrad")
    if args.ocular_transmittance > 1:
        raise InputError(f"--ocular-transmittance must be in (0, 1], got {args.ocular_transmittance:g}")
    eye = glare.EyeModel(args.pupil_diameter_mm * 1e-3, args.eye_focal_length_mm * 1e-3,
                         args.ocular_transmittance)
    th = glare.HazardThresholds(args.burn_coefficient, args.burn_exponent,
                                args.afterimage_coefficient, args.afterimage_exponent)
    return eye, th


def _from_images(args: argparse.Namespace) -> tuple[float, float]:
    if args.sun is None or args.source is None:
        raise InputError("image mode needs both --sun SUN and --source IMAGE")
    _require_positive(args, "dni", "sun_transmittance", "source_transmittance", "exposure_ratio",
                      "threshold_fraction")
    sun = read_image(existing_file(args.sun, "sun image"))
    src = read_image(existing_file(args.source, "source image"))
    if sun.shape != src.shape:
        raise InputError(f"image sizes differ (same camera expected): {args.sun} "
                         f"{sun.shape[1]}x{sun.shape[0]}, {args.source} {src.shape[1]}x{src.shape[0]}")
    try:
        disc = find_sun_disc(sun)
    except SunDiscError as exc:
        raise SunDiscError(f"{args.sun}: {exc}") from None
    try:
        source = glare.segment_glare_source(src, args.threshold_fraction)
    except ValueError as exc:
        raise InputError(f"{args.source}: {exc}") from None
    level = saturation_level_for(src.dtype)
    if level is not None and np.any(src >= level):
        raise InputError(f"{args.source}: {int(np.count_nonzero(src >= level))} source pixels saturated at "
                         f"{level:g}; the corneal irradiance would be underestimated")
    corneal = glare.corneal_from_image(source.sum_counts, disc.sum_counts, args.dni,
                                       sun_transmittance=args.sun_transmittance,
                                       source_transmittance=args.source_transmittance,
                                       exposure_ratio=args.exposure_ratio)
    omega = glare.subtended_angle_from_pixels(source.area_px, disc.radius_px, args.sun_angle_mrad * 1e-3)
    return corneal, omega


def _geometry_curve(args, eye, th) -> glare.GlareCurve:
    if not args.distance_range:
        raise InputError("--geometry needs --distance-range MIN MAX (metres)")
    lo, hi = args.distance_range
    if not (0 < lo < hi and math.isfinite(hi)):
        raise InputError(f"--distance-range must satisfy 0 < MIN < MAX, got {lo:g} {hi:g}")
    if args.points < 2:
        raise InputError(f"--points must be >= 2, got {args.points}")
    x = np.geomspace(lo, hi, args.points)
    if args.geometry == "receiver":
        _require_positive(args, "reflected_power_w", "reflecting_area_m2", "seen_area_m2")
        if not 0 <= args.view_angle_deg < 90:
            raise InputError(f"--view-angle-deg must be in [0, 90), got {args.view_angle_deg:g}")
        return glare.diffuse_glare(x, reflected_power_w=args.reflected_power_w,
                                   reflecting_area_m2=args.reflecting_area_m2, seen_area_m2=args.seen_area_m2,
                                   view_angle_rad=math.radians(args.view_angle_deg), eye=eye, thresholds=th)
    line = args.geometry == "trough"
    aperture_name = "aperture_width_m" if line else "mirror_area_m2"
    _require_positive(args, aperture_name, "dni", "reflectivity")
    if not args.focal_length_m > 0:
        raise InputError(f"--focal-length-m must be > 0 (omit for a flat mirror), "
                         f"got {args.focal_length_m:g}")
    if args.reflectivity > 1:
        raise InputError(f"--reflectivity must be in (0, 1], got {args.reflectivity:g}")
    if not (math.isfinite(args.slope_error_mrad) and args.slope_error_mrad >= 0):
        raise InputError(f"--slope-error-mrad must be >= 0, got {args.slope_error_mrad:g}")
    return glare.specular_glare(x, aperture=getattr(args, aperture_name), focal_length_m=args.focal_length_m,
                                slope_error_rad=args.slope_error_mrad * 1e-3, dni_w_m2=args.dni,
                                reflectivity=args.reflectivity, line_focus=line,
                                sun_angle_rad=args.sun_angle_mrad * 1e-3, eye=eye, thresholds=th)


def _hazard_axes(ax, th: glare.HazardThresholds) -> None:
    omega = np.geomspace(1e-4, 1.0, 400)
    burn = th.burn_w_cm2(omega)
    after = np.minimum(th.afterimage_w_cm2(omega), burn)
    lo, hi = 1e-6, 1e3
    mrad = omega * 1e3
    ax.fill_between(mrad, lo, after, color=ZONE_COLOURS["green"], alpha=0.35,
                    label="low potential for after-image")
    ax.fill_between(mrad, after, burn, color=ZONE_COLOURS["yellow"], alpha=0.35,
                    label="potential for after-image")
    ax.fill_between(mrad, burn, hi, color=ZONE_COLOURS["red"], alpha=0.35,
                    label="potential for permanent eye damage")
    ax.plot(mrad, burn, color=ZONE_COLOURS["red"], lw=1)
    ax.plot(mrad, after, color="#b8860b", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(mrad[0], mrad[-1])
    ax.set_ylim(lo, hi)
    ax.set_xlabel("subtended source angle ω, mrad")
    ax.set_ylabel("retinal irradiance, W/cm²")
    ax.legend(loc="lower left", fontsize=7)


def _write_png(path: str, th: glare.HazardThresholds, points: tuple[np.ndarray, np.ndarray],
               curve: glare.GlareCurve | None) -> None:
    plt = pyplot()

    if curve is None:
        fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=100)
        _hazard_axes(ax, th)
        ax.plot(points[0] * 1e3, points[1], "k*", ms=12)
        ax.set_title("ocular hazard (Ho, Ghanbari & Diver 2011)")
    else:
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.8), dpi=100)
        _hazard_axes(ax, th)
        ax.plot(curve.omega_rad * 1e3, curve.retinal_w_cm2, "k-", lw=1.5)
        ax.set_title("ocular hazard along the distance range")
        for zone, colour in ZONE_COLOURS.items():
            sel = curve.zones == zone
            ax2.plot(curve.distance_m[sel], curve.retinal_w_cm2[sel], ".", color=colour, label=zone)
        ax2.plot(curve.distance_m, th.burn_w_cm2(curve.omega_rad), "--", color=ZONE_COLOURS["red"],
                 lw=1, label="burn threshold at ω(x)")
        ax2.plot(curve.distance_m, th.afterimage_w_cm2(curve.omega_rad), "--", color="#b8860b",
                 lw=1, label="after-image threshold at ω(x)")
        ax2.set_xscale("log")
        ax2.set_yscale("log")
        ax2.set_xlabel("distance, m")
        ax2.set_ylabel("retinal irradiance, W/cm²")
        ax2.legend(fontsize=7)
        ax2.set_title("retinal irradiance and zone vs distance")
    fig.tight_layout()
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    mode = _mode(args)
    eye, th = _eye_and_thresholds(args)
    if args.png and not args.png.lower().endswith(".png"):
        raise InputError(f"--png {args.png}: must end in .png")
    if args.png:
        output_file(args.png, "--png")
    if mode == "geometry":
        curve = _geometry_curve(args, eye, th)
        result = {
            "geometry": args.geometry,
            "curve": [{"distance_m": float(d), "corneal_irradiance_w_m2": float(c),
                       "retinal_irradiance_w_cm2": float(r), "subtended_angle_mrad": float(w * 1e3),
                       "zone": str(z)}
                      for d, c, r, w, z in zip(curve.distance_m, curve.corneal_w_m2, curve.retinal_w_cm2,
                                               curve.omega_rad, curve.zones, strict=True)],
            "zone_ranges": [asdict(r) for r in curve.zone_ranges()],
        }
        if args.png:
            _write_png(args.png, th, (curve.omega_rad, curve.retinal_w_cm2), curve)
        if args.json:
            print_json(result)
        else:
            for r in result["zone_ranges"]:
                print(f"{r['zone']:>6}: {r['from_m']:.4g} m .. {r['to_m']:.4g} m")
        return 0
    if mode == "direct":
        _require_positive(args, "corneal_irradiance_w_m2", "subtended_angle_mrad")
        corneal, omega = args.corneal_irradiance_w_m2, args.subtended_angle_mrad * 1e-3
    else:
        corneal, omega = _from_images(args)
    retinal = float(glare.retinal_irradiance_w_cm2(corneal, omega, eye))
    zone = glare.hazard_zone(retinal, omega, th)
    result = {"retinal_irradiance_w_cm2": retinal, "subtended_angle_mrad": omega * 1e3, "zone": zone}
    if mode == "image":
        result["corneal_irradiance_w_m2"] = corneal
    if args.png:
        _write_png(args.png, th, (np.array([omega]), np.array([retinal])), None)
    if args.json:
        print_json(result)
    else:
        print(f"{zone}: retinal irradiance {retinal:.4g} W/cm² at ω = {omega * 1e3:.4g} mrad")
    return 0
