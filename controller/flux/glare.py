"""Glint and glare hazard: retinal irradiance and hazard zone on the (ω, E_r) plane.

Quantities and units: corneal irradiance E_c in W/m² (irradiance at the eye from the glare
source, measured normal to the line of sight), subtended source angle ω in radians (full
angle), retinal irradiance E_r returned in W/cm² as the hazard plot uses it.

Retinal irradiance of a source of uniform radiance imaged on the retina (Ho et al. 2011):

    E_r = E_c · d_p² · τ / (f² · ω²)

with pupil diameter d_p (2 mm daylight), eye focal length f (17 mm) and ocular transmittance
τ (0.5). Hazard zones (Ho et al. 2011; SGHAT "ocular hazard plot"):

- red: potential for permanent retinal burn, E_r ≥ E_burn(ω) = 0.118 / ω  W/cm² (ω in rad);
- yellow: potential for temporary after-image, E_flash(ω) ≤ E_r < E_burn(ω),
  E_flash(ω) = 3.59e-5 / ω²  W/cm²;
- green: low potential for after-image, E_r < E_flash(ω).

The two boundaries are power laws C·ω^(-n); their coefficients and exponents are fields of
:class:`HazardThresholds` so a site can substitute its own. Above ω ≈ 0.3 mrad the after-image
line lies below the burn line; where they cross (smaller ω) the burn line wins.

Geometry (no image), after Ho et al. 2011:

- a focused heliostat (or a flat one, F = ∞) of area A_h and equivalent diameter
  D_h = √(4 A_h/π) makes at distance x a beam of diameter D(x) = |D_h (1 - x/F)| + β x, with
  β the total beam divergence (sun angle plus reflected slope error, see
  :func:`beam_divergence_rad`). The beam irradiance is I = ρ · DNI · C with C = A_h / A_x =
  (D_h / D(x))², and the glint seen from inside the beam subtends ω = β · √(I/(ρ · DNI)) = β√C;
- a line-focus collector (trough) of aperture width W_h: C = W_h / W(x), same W(x) law;
- a diffuse receiver reflecting power P_d from area A_d (radiance P_d/(π A_d)), of which the
  observer sees A_s at view angle θ and distance r: I_d = (P_d / (π A_d)) · (A_s cos θ / r²),
  ω = 2 √(A_s cos θ / π) / r.

References
----------
Ho, C.K., Ghanbari, C.M., Diver, R.B., "Methodology to assess potential glint and glare
hazards from concentrating solar power plants: analytical models and experimental
validation", J. Sol. Energy Eng. 133 (2011) 031021.
Ho, C.K., Sims, C.A., Yellowhair, J.E., "Solar Glare Hazard Analysis Tool (SGHAT) Technical
Reference Manual", Sandia National Laboratories (2015), ocular hazard plot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.flux.phlux import SUN_ANGLE_RAD

ZONES = ("green", "yellow", "red")


@dataclass(frozen=True)
class EyeModel:
    """Eye parameters: pupil diameter d_p and focal length f in metres, ocular transmittance τ."""

    pupil_diameter_m: float = 2e-3
    focal_length_m: float = 17e-3
    transmittance: float = 0.5


@dataclass(frozen=True)
class HazardThresholds:
    """Hazard-zone boundaries E(ω) = C · ω^(-n) in W/cm², ω in radians.

    Defaults: Ho, Ghanbari & Diver (2011), as drawn in Sandia's SGHAT ocular hazard plot.
    """

    burn_coefficient: float = 0.118
    burn_exponent: float = 1.0
    afterimage_coefficient: float = 3.59e-5
    afterimage_exponent: float = 2.0

    def burn_w_cm2(self, omega_rad):
        """Retinal-burn threshold at subtended angle ω (rad), W/cm²."""
        return self.burn_coefficient * np.asarray(omega_rad, dtype=float) ** (-self.burn_exponent)

    def afterimage_w_cm2(self, omega_rad):
        """Potential-after-image threshold at subtended angle ω (rad), W/cm²."""
        return self.afterimage_coefficient * np.asarray(omega_rad, dtype=float) ** (-self.afterimage_exponent)


def retinal_irradiance_w_cm2(corneal_w_m2, omega_rad, eye: EyeModel = EyeModel()):
    """E_r = E_c · d_p² · τ / (f² · ω²), returned in W/cm².

    corneal_w_m2 : E_c, W/m². omega_rad : ω, full subtended angle of the source, radians.

    References
    ----------
    Ho, Ghanbari & Diver (2011), J. Sol. Energy Eng. 133, 031021 (retinal irradiance).
    """
    omega = np.asarray(omega_rad, dtype=float)
    if np.any(omega <= 0):
        raise ValueError("subtended angle must be > 0")
    e_r = (np.asarray(corneal_w_m2, dtype=float) * eye.pupil_diameter_m**2 * eye.transmittance
           / (eye.focal_length_m**2 * omega**2))
    return e_r * 1e-4


def hazard_zone(retinal_w_cm2, omega_rad, thresholds: HazardThresholds = HazardThresholds()):
    """'green', 'yellow' or 'red' for retinal irradiance (W/cm²) at subtended angle ω (rad).

    Returns a str for scalar input, else an array of str of the broadcast shape.
    """
    e_r = np.asarray(retinal_w_cm2, dtype=float)
    omega = np.asarray(omega_rad, dtype=float)
    level = np.where(e_r >= thresholds.burn_w_cm2(omega), 2,
                     np.where(e_r >= thresholds.afterimage_w_cm2(omega), 1, 0))
    zones = np.asarray(ZONES)[level]
    return str(zones) if zones.ndim == 0 else zones


def corneal_from_image(source_sum: float, sun_sum: float, dni_w_m2: float, *, sun_transmittance: float = 1.0,
                       source_transmittance: float = 1.0, exposure_ratio: float = 1.0) -> float:
    """Corneal irradiance of a glare source photographed with the sun-image camera, W/m².

    Both images integrate irradiance at the camera over their pixels, so the source delivers
    E_c = DNI · Σ_src V / Σ_sun V · (T_sun / T_src) / R, R = t_src / t_sun.

    References
    ----------
    Ho, Ghanbari & Diver (2011), J. Sol. Energy Eng. 133, 031021 (photographic method);
    Ho & Khalsa (2012), J. Sol. Energy Eng. 134, 041004.
    """
    if not (sun_sum > 0 and dni_w_m2 > 0 and exposure_ratio > 0 and source_transmittance > 0):
        raise ValueError("sun sum, DNI, transmittance and exposure ratio must be > 0")
    ratio = (sun_transmittance / source_transmittance) / exposure_ratio
    return float(dni_w_m2 * source_sum / sun_sum * ratio)


def subtended_angle_from_pixels(area_px: float, sun_radius_px: float,
                                sun_angle_rad: float = SUN_ANGLE_RAD) -> float:
    """Full angle of a source covering area_px pixels, as its equivalent disc, from the sun disc
    scale: ω = γ · √(area_px / (π r_sun_px²)), radians."""
    return float(sun_angle_rad * np.sqrt(area_px / (np.pi * sun_radius_px**2)))


def beam_divergence_rad(slope_error_rad: float, sun_angle_rad: float = SUN_ANGLE_RAD) -> float:
    """Total beam divergence β = γ + 4 σ_slope (full angle, radians).

    Reflection doubles a slope error, and the beam edge is taken at ±1 σ of the reflected
    direction, so the slope error widens the full angle by 2 · 2 σ_slope.
    """
    return float(sun_angle_rad + 4.0 * slope_error_rad)


def specular_concentration(distance_m, aperture: float, focal_length_m: float, beta_rad: float,
                           line_focus: bool = False):
    """Area concentration ratio C of a heliostat beam (A_h/A_x) or trough beam (W_h/W_x).

    aperture : heliostat area A_h in m² (point focus) or trough aperture width W_h in m
        (line focus). focal_length_m : F, np.inf for a flat mirror. beta_rad : β.
    distance_m : x, distance(s) along the beam, metres.

    The beam size is D(x) = |D_h (1 - x/F)| + β x with D_h = √(4 A_h/π) (point) or W_h (line).
    """
    x = np.asarray(distance_m, dtype=float)
    size_h = aperture if line_focus else np.sqrt(4.0 * aperture / np.pi)
    defocus = 0.0 if np.isinf(focal_length_m) else 1.0 / focal_length_m
    size_x = np.abs(size_h * (1.0 - x * defocus)) + beta_rad * x
    ratio = size_h / size_x
    return ratio if line_focus else ratio**2


@dataclass(frozen=True)
class GlareCurve:
    """Glare along a distance range: arrays of shape (n,) — distance (m), corneal irradiance
    (W/m²), subtended angle (rad), retinal irradiance (W/cm²) and zone names."""

    distance_m: np.ndarray
    corneal_w_m2: np.ndarray
    omega_rad: np.ndarray
    retinal_w_cm2: np.ndarray
    zones: np.ndarray

    def zone_ranges(self) -> list[ZoneRange]:
        """Runs of equal zone along the curve, in sample order (distances in m, as sampled)."""
        ranges: list[ZoneRange] = []
        for d, z in zip(self.distance_m, self.zones, strict=True):
            if ranges and ranges[-1].zone == z:
                ranges[-1] = ZoneRange(ranges[-1].zone, ranges[-1].from_m, float(d))
            else:
                ranges.append(ZoneRange(str(z), float(d), float(d)))
        return ranges


@dataclass(frozen=True)
class ZoneRange:
    """One hazard zone over the sampled distances ``from_m`` to ``to_m`` (m, inclusive)."""

    zone: str
    from_m: float
    to_m: float


def _curve(distance, corneal, omega, eye, thresholds) -> GlareCurve:
    e_r = retinal_irradiance_w_cm2(corneal, omega, eye)
    zones = np.atleast_1d(hazard_zone(e_r, omega, thresholds))
    return GlareCurve(np.asarray(distance, float), np.asarray(corneal, float), np.asarray(omega, float),
                      np.asarray(e_r, float), zones)


def specular_glare(distance_m, *, aperture: float, focal_length_m: float, slope_error_rad: float,
                   dni_w_m2: float, reflectivity: float, line_focus: bool = False,
                   sun_angle_rad: float = SUN_ANGLE_RAD, eye: EyeModel = EyeModel(),
                   thresholds: HazardThresholds = HazardThresholds()) -> GlareCurve:
    """Glare from inside a specular beam at distances x: I = ρ · DNI · C(x), ω = β √C.

    References
    ----------
    Ho, Ghanbari & Diver (2011), J. Sol. Energy Eng. 133, 031021: heliostat beam
    irradiance and subtended angle; parabolic troughs with C = R_h / R_x.
    """
    beta = beam_divergence_rad(slope_error_rad, sun_angle_rad)
    c = specular_concentration(distance_m, aperture, focal_length_m, beta, line_focus)
    corneal = reflectivity * dni_w_m2 * c
    return _curve(distance_m, corneal, beta * np.sqrt(c), eye, thresholds)


def diffuse_glare(distance_m, *, reflected_power_w: float, reflecting_area_m2: float, seen_area_m2: float,
                  view_angle_rad: float = 0.0, eye: EyeModel = EyeModel(),
                  thresholds: HazardThresholds = HazardThresholds()) -> GlareCurve:
    """Glare from a diffusely reflecting receiver: I_d = (P_d/(π A_d)) · (A_s cos θ / r²),
    ω = 2 √(A_s cos θ / π) / r.

    References
    ----------
    Ho, Ghanbari & Diver (2011), J. Sol. Energy Eng. 133, 031021: diffuse reflection
    from a receiver.
    """
    r = np.asarray(distance_m, dtype=float)
    projected = seen_area_m2 * np.cos(view_angle_rad)
    corneal = reflected_power_w / (np.pi * reflecting_area_m2) * projected / r**2
    omega = 2.0 * np.sqrt(projected / np.pi) / r
    return _curve(r, corneal, omega, eye, thresholds)


@dataclass(frozen=True)
class GlareSource:
    """A glare source segmented in an image: summed background-subtracted counts, its area in
    pixels at half its peak, intensity centroid (x, y) in pixels, background level (counts)."""

    sum_counts: float
    area_px: int
    center_px: tuple[float, float]
    background: float


def segment_glare_source(image: np.ndarray, threshold_fraction: float = 0.1) -> GlareSource:
    """The brightest source in an image.

    The signal is summed over the connected region around the brightest pixel whose level
    exceeds background + threshold_fraction · (peak - background), so dim edges count towards
    the corneal irradiance. The size is the area inside that region above half the peak: for a
    uniform source the half-covered edge pixels split evenly, giving its true area. The
    background is the image median (a glint is small in the frame). Raises ValueError when
    nothing stands out of the background.
    """
    img = np.asarray(image, dtype=np.float64)
    background = float(np.median(img))
    peak_at = np.unravel_index(int(np.argmax(img)), img.shape)
    peak = float(img[peak_at])
    if not peak > background:
        raise ValueError("no glare source above the background")
    from scipy import ndimage  # imported here: it costs every other heliocal command 0.17 s at start
    labels, _ = ndimage.label(img > background + threshold_fraction * (peak - background))
    region = labels == labels[peak_at]
    signal = np.where(region, img - background, 0.0)
    half = region & (img - background >= 0.5 * (peak - background))
    yy, xx = np.indices(img.shape)
    total = float(signal.sum())
    return GlareSource(total, int(half.sum()),
                       (float((signal * xx).sum() / total), float((signal * yy).sum() / total)), background)
