"""Bisector, reflection, ray/plane intersection and error measures against hand values."""

from __future__ import annotations

import math
from datetime import UTC, datetime

import numpy as np
import pytest

from controller.config import LampSource, Site, SunSource
from controller.errors import InputError
from controller.geometry.aiming import (
    aim_normal,
    angle_mrad,
    beam_error_mrad,
    intersect_plane,
    normal_error_mrad,
    reflect,
    reflected_beam,
    source_direction,
)
from controller.geometry.sun import solar_position
from controller.geometry.vectors import azel_to_vector

R2 = math.sqrt(0.5)


def test_aim_normal_bisects():
    # Source at the zenith, target due east on the horizon: normal at 45° towards east.
    n = aim_normal([0, 0, 1], [0, 0, 0], [100, 0, 0])
    assert n == pytest.approx([R2, 0, R2])
    # Source and target in the same direction: normal points at them.
    assert aim_normal([0, 1, 0], [5, 5, 5], [5, 50, 5]) == pytest.approx([0, 1, 0])


def test_reflect_hand_values():
    assert reflect([0, 0, -1], [0, 0, 1]) == pytest.approx([0, 0, 1])
    assert reflect([0, 0, -1], [0, 0, -1]) == pytest.approx([0, 0, 1])  # normal sign is irrelevant
    assert reflect([0, 0, -2], [R2, 0, R2]) == pytest.approx([2, 0, 0])  # length kept
    n = aim_normal([0, 0, 1], [0, 0, 0], [100, 0, 0])
    assert reflected_beam([0, 0, 1], n) == pytest.approx([1, 0, 0])


def test_intersect_plane():
    p = intersect_plane([0, 10, 2], [0, -1, 1], [0, 0, 30], [0, 1, 0])
    assert p == pytest.approx([0, 0, 12])
    with pytest.raises(ValueError, match="parallel"):
        intersect_plane([0, 10, 2], [1, 0, 0], [0, 0, 30], [0, 1, 0])
    with pytest.raises(ValueError, match="behind"):
        intersect_plane([0, 10, 2], [0, 1, 0], [0, 0, 30], [0, 1, 0])


def test_beam_error_is_twice_the_normal_error_in_the_plane_of_incidence():
    s = np.array([0.0, 0.0, 1.0])  # source at the zenith
    n0 = np.array([R2, 0.0, R2])  # incidence angle 45°, plane of incidence = E-U
    d = 1e-3
    tilt_in = np.array([math.sin(math.pi / 4 + d), 0.0, math.cos(math.pi / 4 + d)])
    assert normal_error_mrad(tilt_in, n0) == pytest.approx(1.0, rel=1e-6)
    assert beam_error_mrad(s, tilt_in, n0) == pytest.approx(2.0, rel=1e-6)
    # Tilt across the plane of incidence: beam error 2·δ·cos(45°).
    across = n0 * math.cos(d) + np.array([0.0, 1.0, 0.0]) * math.sin(d)
    assert beam_error_mrad(s, across, n0) == pytest.approx(2.0 * R2, rel=1e-4)


def test_angle_mrad_small_and_large():
    assert angle_mrad([1, 0, 0], [1, 1e-6, 0]) == pytest.approx(1e-3, rel=1e-6)
    assert angle_mrad([1, 0, 0], [-1, 0, 0]) == pytest.approx(1e3 * math.pi)


def test_source_direction_lamp_and_sun():
    lamp = LampSource(kind="lamp", id="lamp", position_enu_m=(0.0, 5.0, 55.0), diameter_m=0.3)
    assert source_direction(lamp, [0.0, 45.0, 25.0]) == pytest.approx([0.0, -0.8, 0.6])
    sun = SunSource(kind="sun")
    with pytest.raises(InputError, match="time and a site"):
        source_direction(sun, [0, 0, 0])
    site = Site(latitude_deg=37.0, longitude_deg=-2.4, elevation_m=500.0, pressure_mbar=955.0,
                temperature_c=15.0)
    when = datetime(2024, 6, 21, 12, 0, tzinfo=UTC)
    pos = solar_position(when, 37.0, -2.4, 500.0, 955.0, 15.0)
    assert source_direction(sun, [0, 0, 0], when=when, site=site) == pytest.approx(
        azel_to_vector(pos.azimuth_deg, pos.elevation_deg))
