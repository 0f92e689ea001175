"""Beam-spot optics: target frame, energy conservation, aim, astigmatism (Coddington)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from simplant.optics import MirrorSurface, TargetGrid, render_spot


def north_target(width=8.0, height=7.0, shape=(256, 256)):
    cfg = SimpleNamespace(center_enu_m=(0.0, 0.0, 30.0), normal=(0.0, 1.0, 0.0), width_m=width,
                          height_m=height)
    return TargetGrid.from_target(cfg, shape)


def test_target_grid_frame_and_round_trip():
    g = north_target()
    # Seen from the field (north), image +x is west and +y is down (PAINT: left = east).
    assert np.allclose(g.u_axis, [-1, 0, 0]) and np.allclose(g.v_axis, [0, 0, -1])
    # pixel centre (0, 0): half a pixel in from the top-left corner (east, up).
    p = g.pixel_to_enu(0.0, 0.0)
    assert np.allclose(p, [4.0 - 4.0 / 256, 0.0, 30.0 + 3.5 - 3.5 / 256])
    assert np.allclose(g.enu_to_pixel(g.center), (127.5, 127.5))
    xs, ys = np.array([3.2, 200.0]), np.array([17.0, 90.5])
    back = g.enu_to_pixel(g.pixel_to_enu(xs, ys))
    assert np.allclose(back[0], xs) and np.allclose(back[1], ys)


def _aimed(helio, source, aim):
    s = (source - helio) / np.linalg.norm(source - helio)
    a = (aim - helio) / np.linalg.norm(aim - helio)
    return s, (s + a) / np.linalg.norm(s + a)


def test_energy_is_conserved_and_centroid_on_aim():
    g = north_target()
    helio = np.array([-22.5, 40.0, 2.0])
    lamp = np.array([0.0, 5.0, 55.0])
    s, n = _aimed(helio, lamp, g.center)
    m = MirrorSurface(3.2, 2.56, 53.8, 1.5, 0.93)
    img = render_spot(helio, n, lamp, 0.3 / np.linalg.norm(lamp - helio), m, g)
    du, dv = g.pixel_size_m
    expected = 3.2 * 2.56 * 0.93 * float(s @ n)  # A ρ cos θ per W/m² of source irradiance
    assert img.sum() * du * dv == pytest.approx(expected, rel=1e-9)
    ys, xs = np.indices(img.shape)
    cx, cy = (img * xs).sum() / img.sum(), (img * ys).sum() / img.sum()
    assert cx == pytest.approx(127.5, abs=0.15) and cy == pytest.approx(127.5, abs=0.15)


def test_spill_loses_power():
    g = north_target(0.5, 0.5, (64, 64))
    helio = np.array([0.0, 40.0, 2.0])
    s, n = _aimed(helio, np.array([0.0, 5.0, 55.0]), g.center)
    img = render_spot(helio, n, np.array([0.0, 5.0, 55.0]), 0.005, MirrorSurface(3.2, 2.56, 50.0, 1.5), g)
    du, dv = g.pixel_size_m
    assert img.sum() * du * dv < 0.5 * 3.2 * 2.56 * 0.93 * float(s @ n)


def _widths(theta_deg, distance, f=50.0):
    """Spot RMS widths (u = sagittal, v = tangential) on a screen normal to the reflected ray."""
    th = math.radians(theta_deg)
    n = np.array([0.0, 0.0, 1.0])  # mirror faces up; plane of incidence = y-z (tangential = e_h = y)
    s = np.array([0.0, -math.sin(th), math.cos(th)])
    r = np.array([0.0, math.sin(th), math.cos(th)])
    centre = distance * r
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(u, -r)
    g = TargetGrid(centre, -r, u, v, 0.4, 0.4, (200, 200))
    img = render_spot(np.zeros(3), n, s, 1e-5, MirrorSurface(2.0, 2.0, f, 0.0), g,
                      source_is_direction=True, n_rays=60_000)
    ys, xs = np.indices(img.shape)
    w = img / img.sum()
    cx, cy = (w * xs).sum(), (w * ys).sum()
    return math.sqrt((w * (xs - cx) ** 2).sum()), math.sqrt((w * (ys - cy) ** 2).sum())


def test_astigmatism_sagittal_and_tangential_foci():
    # Coddington: tangential focus f cos θ, sagittal f / cos θ. θ = 30°, f = 50 m:
    # f cos θ = 43.30 m, f / cos θ = 57.74 m.
    dists = np.arange(38.0, 64.0, 1.0)
    wu, wv = np.array([_widths(30.0, d) for d in dists]).T
    assert dists[np.argmin(wv)] == pytest.approx(50 * math.cos(math.radians(30)), abs=1.5)
    assert dists[np.argmin(wu)] == pytest.approx(50 / math.cos(math.radians(30)), abs=1.5)
    # At normal incidence both foci coincide at f.
    w0 = np.array([_widths(0.0, d) for d in (45.0, 50.0, 55.0)])
    assert np.argmin(w0[:, 0]) == 1 and np.argmin(w0[:, 1]) == 1


def test_slope_error_widens_spot_by_twice_the_slope():
    # Flat mirror (huge f), tiny source: spot RMS width ≈ 2 σ_slope · distance.
    n = np.array([0.0, 0.0, 1.0])
    g = TargetGrid(np.array([0.0, 0.0, 100.0]), np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]),
                   np.array([0.0, -1.0, 0.0]), 6.0, 6.0, (300, 300))
    img = render_spot(np.zeros(3), n, n, 1e-6, MirrorSurface(0.01, 0.01, 1e9, 5.0), g,
                      source_is_direction=True, n_rays=100_000)
    xs = np.indices(img.shape)[1] * 0.02
    w = img / img.sum()
    sx = math.sqrt((w * (xs - (w * xs).sum()) ** 2).sum())
    assert sx == pytest.approx(2 * 5e-3 * 100.0, rel=0.03)


def test_source_behind_mirror_gives_no_light():
    g = north_target()
    lamp = np.array([0.0, 5.0, 55.0])
    img = render_spot(np.array([0.0, 40.0, 2.0]), np.array([0.0, 0.0, -1.0]), lamp, 0.005,
                      MirrorSurface(3.2, 2.56, 50.0, 1.5), g)
    assert img.shape == (256, 256) and not img.any()


def test_deformation_slope_tilts_beam_by_twice_the_slope():
    # Mirror facing up (e_w falls back to east); a +1 mrad dz/dx tilts the local normal towards
    # -east, so the reflected beam moves 2 mrad x 100 m = 0.2 m west = -10 px on a 2 cm grid.
    n = np.array([0.0, 0.0, 1.0])
    g = TargetGrid(np.array([0.0, 0.0, 100.0]), np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]),
                   np.array([0.0, -1.0, 0.0]), 2.0, 2.0, (100, 100))
    def canting(x, y):
        return np.full_like(x, 1e-3), np.zeros_like(y)

    tilt = MirrorSurface(0.2, 0.2, 1e9, 0.0, deformation=canting)
    img = render_spot(np.zeros(3), n, n, 1e-5, tilt, g, source_is_direction=True, n_rays=20_000)
    xs = np.indices(img.shape)[1]
    assert (img * xs).sum() / img.sum() == pytest.approx(49.5 - 10.0, abs=0.05)
