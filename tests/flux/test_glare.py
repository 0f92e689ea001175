"""Glare hazard: retinal irradiance, threshold curves and zones at hand-computed points, the
geometry models, and the photographic (sun-image-scaled) corneal irradiance."""

import numpy as np
import pytest

from controller.flux import glare
from controller.flux.sun_disc import find_sun_disc


def test_retinal_irradiance_of_the_sun_by_hand():
    # 1000 W/m² · (2 mm)² · 0.5 / ((17 mm)² · (9.3 mrad)²) = 2e-3 / 2.499561e-8 = 80014 W/m²
    assert glare.retinal_irradiance_w_cm2(1000.0, 9.3e-3) == pytest.approx(8.00141, rel=1e-5)
    eye = glare.EyeModel(pupil_diameter_m=4e-3, focal_length_m=17e-3, transmittance=0.5)
    assert glare.retinal_irradiance_w_cm2(1000.0, 9.3e-3, eye) == pytest.approx(4 * 8.00141, rel=1e-5)


@pytest.mark.parametrize("omega, burn, after", [
    (1e-3, 118.0, 35.9),       # 0.118/1e-3, 3.59e-5/1e-6
    (1e-2, 11.8, 0.359),
    (1e-1, 1.18, 3.59e-3),
])
def test_threshold_curves_by_hand(omega, burn, after):
    th = glare.HazardThresholds()
    assert th.burn_w_cm2(omega) == pytest.approx(burn, rel=1e-9)
    assert th.afterimage_w_cm2(omega) == pytest.approx(after, rel=1e-9)


@pytest.mark.parametrize("e_r, omega, zone", [
    (0.1, 1e-2, "green"),     # below 0.359
    (0.359, 1e-2, "yellow"),  # on the after-image line
    (1.0, 1e-2, "yellow"),
    (11.8, 1e-2, "red"),      # on the burn line
    (20.0, 1e-3, "green"),    # 20 < 35.9 at 1 mrad
    (8.00141, 9.3e-3, "yellow"),  # staring at the sun: after-image, no burn (12.7 W/cm²)
    (2000.0, 1e-4, "red"),    # below ω = 0.30 mrad the lines cross; burn (1180) wins
])
def test_zones_at_hand_points(e_r, omega, zone):
    assert glare.hazard_zone(e_r, omega) == zone


def test_thresholds_are_configurable():
    strict = glare.HazardThresholds(burn_coefficient=0.05, afterimage_coefficient=1e-5)
    # 8 W/cm² at 9.3 mrad: burn line 0.05/9.3e-3 = 5.38 W/cm² -> red
    assert glare.hazard_zone(8.0, 9.3e-3, strict) == "red"
    assert glare.hazard_zone(8.0, 9.3e-3) == "yellow"


def test_flat_heliostat_beam_by_hand():
    # A_h = π m² (D_h = 2 m), no slope error: β = 9.3 mrad; at 1 km D = 2 + 9.3 = 11.3 m,
    # C = (2/11.3)² = 0.0313258, I = 0.9·1000·C = 28.1932 W/m², ω = β·2/11.3 = 1.646018 mrad
    c = glare.specular_glare(np.array([1000.0]), aperture=np.pi, focal_length_m=np.inf, slope_error_rad=0.0,
                             dni_w_m2=1000.0, reflectivity=0.9)
    assert c.corneal_w_m2[0] == pytest.approx(28.1932, rel=1e-5)
    assert c.omega_rad[0] == pytest.approx(1.646018e-3, rel=1e-6)


def test_focused_heliostat_at_its_focus_by_hand():
    # F = 500 m, σ = 1 mrad: β = 9.3 + 4 = 13.3 mrad; at x = F the beam is β·F = 6.65 m wide,
    # C = (2/6.65)² = 0.0904517, I = 81.4065 W/m², ω = β√C = D_h/F = 4 mrad
    c = glare.specular_glare(np.array([500.0]), aperture=np.pi, focal_length_m=500.0, slope_error_rad=1e-3,
                             dni_w_m2=1000.0, reflectivity=0.9)
    assert c.corneal_w_m2[0] == pytest.approx(81.4065, rel=1e-5)
    assert c.omega_rad[0] == pytest.approx(4e-3, rel=1e-9)


def test_trough_line_focus_by_hand():
    # flat 5 m aperture, no slope error, 100 m: W = 5 + 0.93 = 5.93 m, C = 5/5.93 = 0.843170
    c = glare.specular_concentration(np.array([100.0]), 5.0, np.inf, 9.3e-3, line_focus=True)
    assert c[0] == pytest.approx(0.843170, rel=1e-5)


def test_diffuse_receiver_by_hand():
    # P_d 1 MW from 100 m², 100 m² seen at 60°, 1 km: I = 1e6/(π·100) · 50/1e6 = 0.1591549 W/m²,
    # ω = 2·√(50/π)/1000 = 7.978846 mrad
    c = glare.diffuse_glare(np.array([1000.0]), reflected_power_w=1e6, reflecting_area_m2=100.0,
                            seen_area_m2=100.0, view_angle_rad=np.radians(60.0))
    assert c.corneal_w_m2[0] == pytest.approx(0.1591549, rel=1e-6)
    assert c.omega_rad[0] == pytest.approx(7.978846e-3, rel=1e-6)


def test_specular_retinal_irradiance_is_constant_and_zone_follows_the_angle():
    # With ω = β√C, E_r = ρ·DNI·d²τ/(f²β²) whatever the distance (radiance is conserved):
    # 0.9·1000·4e-6·0.5 / (2.89e-4 · (17.3e-3)²) = 20810.6 W/m² = 2.08106 W/cm² (σ = 2 mrad).
    # The after-image line reaches it at ω* = √(3.59e-5 / 2.08106) = 4.15341 mrad.
    x = np.geomspace(10, 5000, 60)
    c = glare.specular_glare(x, aperture=40.0, focal_length_m=np.inf, slope_error_rad=2e-3, dni_w_m2=1000.0,
                             reflectivity=0.9)
    assert c.retinal_w_cm2 == pytest.approx(np.full(60, 2.08106), rel=1e-5)
    assert np.all(np.diff(c.omega_rad) < 0)
    assert list(c.zones) == ["yellow" if w > 4.15341e-3 else "green" for w in c.omega_rad]
    assert c.zones[0] == "yellow" and c.zones[-1] == "green"


def test_corneal_irradiance_from_images(camera, rng, disc_renderer):
    # A uniform glint of radius 10 px (ω = 9.3·10/40 = 2.325 mrad) delivering 400 W/m² at the
    # camera, photographed through ND 1e-3; the sun (DNI 900) through ND 1e-2, same exposure.
    sun = camera.expose(camera.sun_rate(900.0, 0.01), 1e-3, rng)
    spot = disc_renderer(camera.shape, (70.4, 120.2), 10.0, u=0.0)
    rate = camera.k * 1e-3 * 400.0 * spot / spot.sum()
    img = camera.expose(rate, 1e-3, rng)
    disc = find_sun_disc(sun)
    src = glare.segment_glare_source(img)
    e_c = glare.corneal_from_image(src.sum_counts, disc.sum_counts, 900.0, sun_transmittance=0.01,
                                   source_transmittance=1e-3)
    omega = glare.subtended_angle_from_pixels(src.area_px, disc.radius_px)
    assert e_c == pytest.approx(400.0, rel=0.03)
    assert omega == pytest.approx(2.325e-3, rel=0.03)
    assert src.center_px == pytest.approx((70.4, 120.2), abs=0.1)


def test_zone_ranges_are_runs_of_equal_zone():
    from controller.flux.glare import GlareCurve, ZoneRange

    d = np.array([10.0, 20.0, 40.0, 80.0, 160.0])
    z = np.array(["red", "yellow", "yellow", "green", "green"])
    curve = GlareCurve(d, d, d, d, z)
    assert curve.zone_ranges() == [ZoneRange("red", 10.0, 10.0), ZoneRange("yellow", 20.0, 40.0),
                                   ZoneRange("green", 80.0, 160.0)]
