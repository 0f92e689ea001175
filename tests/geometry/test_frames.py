"""WGS84 -> ENU against hand-computed radii of curvature, and on the real Jülich geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.geometry.frames import enu_to_wgs84, paint_azimuth_to_north, wgs84_to_enu

A, F = 6378137.0, 1 / 298.257223563
E2 = F * (2 - F)


def _radii(lat_deg: float) -> tuple[float, float]:
    """Meridian (M) and prime-vertical (N) radii of curvature, m (textbook formulas)."""
    s2 = math.sin(math.radians(lat_deg)) ** 2
    return A * (1 - E2) / (1 - E2 * s2) ** 1.5, A / math.sqrt(1 - E2 * s2)


@pytest.mark.parametrize("lat0", [0.0, 37.0, 50.913421])
def test_small_offsets_match_radii_of_curvature(lat0):
    m, n = _radii(lat0)
    d = 1e-4  # degrees: ~11 m, where the curvature terms are below 0.1 mm
    north = wgs84_to_enu(lat0 + d, 6.0, 100.0, lat0, 6.0, 100.0)
    east = wgs84_to_enu(lat0, 6.0 + d, 100.0, lat0, 6.0, 100.0)
    up = wgs84_to_enu(lat0, 6.0, 142.5, lat0, 6.0, 100.0)
    assert north == pytest.approx([0.0, (m + 100.0) * math.radians(d), 0.0], abs=1e-4)
    assert east == pytest.approx([(n + 100.0) * math.cos(math.radians(lat0)) * math.radians(d), 0.0, 0.0],
                                 abs=1e-4)
    assert up == pytest.approx([0.0, 0.0, 42.5], abs=1e-9)


def test_round_trip_through_wgs84():
    o = (50.913421, 6.387825, 87.0)
    pts = np.array([[13.26, 24.72, 1.69], [-1000.0, 2500.0, 300.0], [0.0, 0.0, 0.0]])
    back = wgs84_to_enu(*enu_to_wgs84(pts, *o).T, *o)
    assert back == pytest.approx(pts, abs=1e-6)


def test_paint_spots_lie_on_their_north_facing_targets(paint_records, tower, origin):
    """Every UTIS and HeliOS focal spot is on its target plane (normal north): its north
    coordinate equals the target centre's to within the target's flatness (~3 cm)."""
    for r in paint_records:
        centre = wgs84_to_enu(*tower[r["target_name"]]["coordinates"]["center"], *origin)
        for method in ("UTIS", "HeliOS"):
            spot = wgs84_to_enu(*r["focal_spot"][method], *origin)
            assert abs(spot[1] - centre[1]) < 0.03
            assert abs(spot[0] - centre[0]) < 4.3 and abs(spot[2] - centre[2]) < 3.6  # on the 8.6x7.2 m
        utis = wgs84_to_enu(*r["focal_spot"]["UTIS"], *origin)
        helios = wgs84_to_enu(*r["focal_spot"]["HeliOS"], *origin)
        assert np.linalg.norm(utis - helios) < 0.5  # README: the methods differ by roughly 0.1 m


def test_target_corners_span_the_stated_size(tower, origin):
    """The upper tower target is 8.6 m wide and 7.2 m high (README: one 256-px pixel ≈ 34 mm)."""
    c = tower["solar_tower_juelich_upper"]["coordinates"]
    ul, ur, ll = (wgs84_to_enu(*c[k], *origin) for k in ("upper_left", "upper_right", "lower_left"))
    assert np.linalg.norm(ul - ur) == pytest.approx(8.6, abs=0.05)
    assert np.linalg.norm(ul - ll) == pytest.approx(7.2, abs=0.05)
    assert ul[0] > ur[0]  # seen from the north (camera faces south), left is east


@pytest.mark.parametrize("paint, ours", [(0.0, 180.0), (90.0, 90.0), (-90.0, 270.0), (180.0, 0.0),
                                         (-85.60, 265.60), (36.04, 143.96)])
def test_paint_azimuth_conversion(paint, ours):
    assert float(paint_azimuth_to_north(paint)) == pytest.approx(ours, abs=1e-9)
