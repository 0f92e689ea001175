"""Jacobian correction from a measured beam offset: hand-computed geometry and a closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.geometry.aiming import intersect_plane, reflected_beam, source_direction
from controller.geometry.correction import correction_from_offset
from controller.geometry.error_model import TrackingErrorParams, actual_normal
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.vectors import azel_to_vector

PLANE = (np.array([0.0, -50.0, 0.0]), np.array([0.0, 1.0, 0.0]))  # north-facing, 50 m south


@pytest.fixture()
def bench(aa39):
    """AA39 at the origin, sun 60° high due south, normal at α = 0, ε = 60° so that the beam
    goes due south horizontally onto the plane y = −50 m (incidence angle 30°)."""
    kin = HeliostatKinematics("T", np.zeros(3), aa39.azimuth, aa39.elevation)
    az = float(kin.azimuth.steps_float(0.0))
    el = float(kin.elevation.steps_float(math.radians(60.0)))
    sun = azel_to_vector(180.0, 60.0)
    assert reflected_beam(sun, kin.normal(az, el)) == pytest.approx([0, -1, 0], abs=1e-12)
    return kin, az, el, sun


def test_vertical_offset_needs_elevation_only(bench):
    kin, az, el, sun = bench
    c = correction_from_offset(kin, az, el, sun, np.zeros(3), PLANE, [0.0, 0.0, 0.1])
    # In the plane of incidence the beam turns twice the normal: 0.1 m / 50 m / 2 = 1 mrad.
    assert abs(c.del_deg) == pytest.approx(math.degrees(1e-3), rel=1e-4)
    assert abs(c.daz_deg) < 1e-9 and c.daz_steps == 0
    assert c.residual_m < 1e-9


def test_horizontal_offset_needs_azimuth_only(bench):
    kin, az, el, sun = bench
    c = correction_from_offset(kin, az, el, sun, np.zeros(3), PLANE, [0.1, 0.0, 0.0])
    # Across the plane of incidence the beam turns 2·cos(30°) times the normal:
    # 0.1 m / 50 m = 2 mrad of beam -> 2 / (2 cos 30°) = 1.1547 mrad of azimuth.
    assert abs(c.daz_deg) == pytest.approx(math.degrees(2e-3 / (2 * math.cos(math.radians(30)))), rel=1e-4)
    assert abs(c.del_deg) < 1e-9
    # The step count matches the angle through the actuator (one step ≈ 20 µrad).
    dtheta = kin.azimuth.angle(az + c.daz_steps) - kin.azimuth.angle(az)
    assert dtheta == pytest.approx(math.radians(c.daz_deg), abs=3e-5)


def test_correction_closes_the_loop_on_the_demo_plant(demo_config):
    """A heliostat with hidden errors misses the target; one correction from the measured
    offset puts the beam back within step quantisation (a few mm at 50-70 m)."""
    cfg = demo_config
    target = cfg.target()
    centre = np.array(target.center_enu_m)
    hidden = TrackingErrorParams(az_offset=2e-3, el_offset=-1.5e-3, tilt_east=1e-3, mirror_offset=0.7e-3)
    for h in cfg.heliostats[::5]:
        kin = HeliostatKinematics.from_config(h)
        sun = source_direction(cfg.light_source("lamp"), kin.position)

        def spot(az, el, kin=kin, sun=sun):
            beam = reflected_beam(sun, actual_normal(kin, hidden, az, el))
            return intersect_plane(kin.mirror_center(az, el), beam, target.center_enu_m, target.normal)

        az, el = kin.aim(sun, centre)
        offset = spot(az, el) - centre
        assert np.linalg.norm(offset) > 0.2
        c = correction_from_offset(kin, az, el, sun, None, target, offset)
        assert np.linalg.norm(spot(az + c.daz_steps, el + c.del_steps) - centre) < 0.01
