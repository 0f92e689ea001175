"""Irradiance maps, beam power and reflectivity from a target image and a sun image (PHLUX).

The camera photographs a Lambertian target lit by a beam, and the Sun through a neutral-
density filter. Both images share the lens and sensor, so the Sun's disc calibrates the
camera: its summed signal Σ_sun V corresponds to the measured DNI, and its radius in pixels
r_sun_px, for the known solar angle γ, fixes the solid angle seen by one pixel,

    Ω_px = π tan²(γ/2) / (π r_sun_px²) = tan²(γ/2) / r_sun_px²       [sr].

A Lambertian surface of reflectivity ρ under irradiance E has radiance ρE/π in every
direction, so a target pixel reads V_i ∝ (ρ E_i/π) Ω_px, while Σ_sun V ∝ DNI. Dividing,

    E_i = DNI · π · r_sun_px² · V_i / (ρ · tan²(γ/2) · Σ_sun V) · (T_sun / T_target) / R

with T the ND-filter transmittances of the two images and R = t_target / t_sun the ratio of
exposures. Distance and viewing angle cancel: they change the footprint of a pixel, not its
signal. They enter only the power: a pixel covers r² Ω_px / cos θ of target at distance r and
view angle θ (angle between the target normal and the line of sight).

Units: W/m² for irradiance and DNI, W for power, metres, radians inside (degrees only at the
CLI edge). Images: (rows, cols), x = column, y = row.

References
----------
Ho, C.K., Khalsa, S.S., "A photographic flux mapping method for concentrating solar
collectors and receivers", J. Sol. Energy Eng. 134 (2012) 041004: irradiance from
the sun image, pixel solid angle and area, beam power, reflectivity calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Angle subtended by the solar disc, radians (the PHLUX default, 9.3 mrad).
SUN_ANGLE_RAD = 9.3e-3


def pixel_solid_angle(sun_radius_px: float, sun_angle_rad: float = SUN_ANGLE_RAD) -> float:
    """Solid angle of one pixel, Ω_px = tan²(γ/2) / r_sun_px² [sr].

    The Sun's disc (solid angle π tan²(γ/2)) covers π r_sun_px² pixels.

    References
    ----------
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004 (pixel solid angle from the sun disc).
    """
    if sun_radius_px <= 0 or sun_angle_rad <= 0:
        raise ValueError("sun radius (px) and sun angle (rad) must be > 0")
    return float(np.tan(sun_angle_rad / 2.0) ** 2 / sun_radius_px**2)


def irradiance_from_sun_image(values: np.ndarray, sun_sum: float, sun_radius_px: float, dni_w_m2: float,
                              reflectivity: float, *, sun_angle_rad: float = SUN_ANGLE_RAD,
                              sun_transmittance: float = 1.0, target_transmittance: float = 1.0,
                              exposure_ratio: float = 1.0) -> np.ndarray:
    """Irradiance on a Lambertian target, per pixel.

        E_i = DNI · π · r_sun_px² · V_i / (ρ · tan²(γ/2) · Σ_sun V) · (T_sun / T_target) / R

    Parameters
    ----------
    values : array (rows, cols), V_i, linear target counts with ambient (beam-off image, or
        dark level) already subtracted.
    sun_sum : Σ_sun V, background-subtracted counts summed over the sun disc.
    sun_radius_px : r_sun_px, sun disc radius in pixels.
    dni_w_m2 : direct normal irradiance when the sun image was taken, W/m².
    reflectivity : ρ, hemispherical (Lambertian) reflectivity of the target, 0-1.
    sun_angle_rad : γ, full angle subtended by the Sun, radians.
    sun_transmittance, target_transmittance : ND-filter transmittances in front of the camera
        for the sun and the target image.
    exposure_ratio : R = (target exposure) / (sun exposure), for exposure times (or any
        linear exposure setting).

    Returns
    -------
    array (rows, cols), float64, irradiance in W/m².

    References
    ----------
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004 (PHLUX irradiance relation).
    """
    for name, v in (("sun_sum", sun_sum), ("dni_w_m2", dni_w_m2), ("reflectivity", reflectivity),
                    ("sun_transmittance", sun_transmittance),
                    ("target_transmittance", target_transmittance), ("exposure_ratio", exposure_ratio)):
        if not v > 0:
            raise ValueError(f"{name} must be > 0, got {v}")
    omega = pixel_solid_angle(sun_radius_px, sun_angle_rad)
    scale = dni_w_m2 * np.pi / (reflectivity * omega * sun_sum)
    scale *= (sun_transmittance / target_transmittance) / exposure_ratio
    return np.asarray(values, dtype=np.float64) * scale


def pixel_area_m2(distance_m: float, view_angle_rad: float, sun_radius_px: float,
                  sun_angle_rad: float = SUN_ANGLE_RAD) -> float:
    """Area of a plane target covered by one pixel, r² · tan²(γ/2) / r_sun_px² / cos θ [m²].

    distance_m : r, camera to target, metres. view_angle_rad : θ, angle between the target
    normal and the line of sight, radians (< π/2).

    References
    ----------
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004 (pixel area and total power).
    """
    if distance_m <= 0:
        raise ValueError(f"distance must be > 0 m, got {distance_m}")
    cos_t = np.cos(view_angle_rad)
    if not cos_t > 1e-6:
        raise ValueError(f"view angle must be below 90°, got {np.degrees(view_angle_rad):.3g}°")
    return float(distance_m**2 * pixel_solid_angle(sun_radius_px, sun_angle_rad) / cos_t)


def total_power_w(irradiance_w_m2: np.ndarray, pixel_area: float | np.ndarray) -> float:
    """Beam power P = Σ_i E_i · A_i [W] for irradiance (W/m²) and pixel areas (m², scalar or
    an array of the image's shape)."""
    return float(np.sum(np.asarray(irradiance_w_m2, dtype=np.float64) * pixel_area))


def tube_arc_px(offset_px: np.ndarray, tube_radius_px: float) -> np.ndarray:
    """Tube surface seen by one pixel column, as arc length in pixel units.

    Geometry: tubes of radius R (pixels, as imaged) with axes along the image columns,
    viewed perpendicular to the panel from far away (orthographic), so the camera sees each
    tube's full front hemi-cylinder. A surface point at angle φ from the line of sight
    projects to u = R sin φ across the tube (u = pixel centre offset from the tube axis). The
    pixel column [u - ½, u + ½] therefore covers the arc

        s(u) = R · (asin(clip((u + ½)/R)) - asin(clip((u - ½)/R)))

    which tends to 1/cos φ for R ≫ 1 and stays finite at the limb (where 1/cos φ diverges).
    Summed over a tube it gives the half-circumference π R. Returns 0 outside the tube.

    offset_px : array, pixel-centre offsets u from the tube axis, pixels.
    tube_radius_px : R, tube radius in pixels.
    """
    u = np.asarray(offset_px, dtype=np.float64)
    if tube_radius_px <= 0:
        raise ValueError("tube radius must be > 0 px")
    hi = np.arcsin(np.clip((u + 0.5) / tube_radius_px, -1.0, 1.0))
    lo = np.arcsin(np.clip((u - 0.5) / tube_radius_px, -1.0, 1.0))
    return tube_radius_px * (hi - lo)


def tube_radius_m(tube_radius_px: float, distance_m: float, sun_radius_px: float,
                  sun_angle_rad: float = SUN_ANGLE_RAD) -> float:
    """Tube radius in metres from its radius in pixels relative to the sun radius:
    R_m = r · tan(γ/2) · R_px / r_sun_px (the tube subtends R_px/r_sun_px sun radii)."""
    return float(distance_m * np.tan(sun_angle_rad / 2.0) * tube_radius_px / sun_radius_px)


def tube_pixel_area_m2(offset_px: np.ndarray, tube_radius_px: float, distance_m: float,
                       sun_radius_px: float, sun_angle_rad: float = SUN_ANGLE_RAD) -> np.ndarray:
    """Tube surface area covered by each pixel, A(u) = r² · tan²(γ/2) / r_sun_px² · s(u) [m²].

    The flat-pixel area of :func:`pixel_area_m2` (camera on the panel normal, θ = 0) times the
    arc factor s(u) of :func:`tube_arc_px`, which depends only on the pixel's offset u from
    the tube axis and on the tube radius R_px. Camera far from the panel compared with the tube
    radius, so that it sees the full front hemi-cylinder.

    offset_px : pixel-centre offsets u from the tube axis, pixels.
    tube_radius_px : R_px, tube radius as imaged, pixels.
    distance_m : r, camera to panel, metres. sun_radius_px, sun_angle_rad : as for Ω_px.

    References
    ----------
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004 (pixel area), applied per tube
    surface element.
    """
    flat = pixel_area_m2(distance_m, 0.0, sun_radius_px, sun_angle_rad)
    return flat * tube_arc_px(offset_px, tube_radius_px)


def tube_panel_area_map(shape: tuple[int, int], axes_x_px: np.ndarray, tube_radius_px: float,
                        distance_m: float, sun_radius_px: float,
                        sun_angle_rad: float = SUN_ANGLE_RAD) -> np.ndarray:
    """Per-pixel tube-surface area (m²) for a panel of vertical tubes, shape (rows, cols).

    axes_x_px : x (column) of each tube axis, pixels. A column where two touching tubes meet
    sees the limb of both, so the areas of all tubes are summed per column; pixels outside every
    tube get 0. See :func:`tube_pixel_area_m2`.
    """
    axes = np.asarray(axes_x_px, dtype=np.float64).ravel()
    if axes.size == 0:
        raise ValueError("no tube axes given")
    cols = np.arange(shape[1], dtype=np.float64)
    offsets = cols[:, None] - axes[None, :]
    area = tube_pixel_area_m2(offsets, tube_radius_px, distance_m, sun_radius_px, sun_angle_rad).sum(axis=1)
    return np.broadcast_to(area, shape).copy()


def reflectivity_from_beam_power(power_at_unit_reflectivity_w: float, dni_w_m2: float, mirror_area_m2: float,
                                 mirror_reflectivity: float, cos_incidence: float) -> float:
    """Target reflectivity from one heliostat beam of known power, with no spillage.

    The beam carries P = DNI · A_mirror · ρ_mirror · cos(incidence). The image evaluated with
    ρ = 1 gives P₁ = Σ E_i A_i; since E scales as 1/ρ, ρ = P₁ / P.

    References
    ----------
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004, reflectivity calibration.
    """
    beam = dni_w_m2 * mirror_area_m2 * mirror_reflectivity * cos_incidence
    if not beam > 0:
        raise ValueError(f"beam power must be > 0 W, got {beam}")
    return float(power_at_unit_reflectivity_w / beam)


def reflectivity_from_known_power(measured_power_w: float, assumed_reflectivity: float,
                                  known_power_w: float) -> float:
    """Target reflectivity that makes the measured beam power equal a known one (W).

    E scales as 1/ρ, so a map evaluated with ρ_assumed giving P_measured gives
    P₁ = ρ_assumed · P_measured at ρ = 1, and ρ = P₁ / P_known (Ho & Khalsa 2012).
    """
    if not known_power_w > 0:
        raise ValueError(f"known power must be > 0 W, got {known_power_w}")
    return float(assumed_reflectivity * measured_power_w / known_power_w)


def reflectivity_from_coupon(target_values: np.ndarray, coupon_values: np.ndarray,
                             coupon_reflectivity: float) -> float:
    """Target reflectivity from a reference coupon under the same irradiance.

    Both Lambertian, same irradiance, same camera: V ∝ ρ, so ρ_target = ρ_coupon · V̄_target /
    V̄_coupon with V̄ the mean ambient-subtracted counts over each region.
    """
    vc = float(np.mean(coupon_values))
    if not vc > 0:
        raise ValueError("coupon region has no signal above ambient")
    return float(coupon_reflectivity * np.mean(target_values) / vc)


@dataclass(frozen=True)
class Hotspot:
    """A local maximum of a flux map: pixel (x, y) and irradiance w_m2 (W/m²)."""

    x: int
    y: int
    w_m2: float


def find_hotspots(irradiance_w_m2: np.ndarray, count: int = 5, min_separation_px: int = 5,
                  min_fraction: float = 0.5) -> list[Hotspot]:
    """Up to ``count`` local maxima of the 3×3-smoothed map, at least ``min_separation_px`` apart
    and at least ``min_fraction`` of the peak, highest first. w_m2 is the smoothed value, so
    a single noisy pixel is not reported as a hot spot."""
    e = np.asarray(irradiance_w_m2, dtype=np.float32)
    smooth = cv2.blur(e, (3, 3))
    size = 2 * int(min_separation_px) + 1
    local_max = smooth >= cv2.dilate(smooth, np.ones((size, size), np.uint8))
    peak = float(smooth.max())
    if not peak > 0:
        return []
    ys, xs = np.nonzero(local_max & (smooth >= min_fraction * peak))
    order = np.argsort(-smooth[ys, xs], kind="stable")
    spots: list[Hotspot] = []
    # A flat top yields several equal maxima; keep the first of each cluster.
    for i in order:
        if len(spots) == count:
            break
        if all(max(abs(int(xs[i]) - s.x), abs(int(ys[i]) - s.y)) > min_separation_px for s in spots):
            spots.append(Hotspot(int(xs[i]), int(ys[i]), float(smooth[ys[i], xs[i]])))
    return spots
