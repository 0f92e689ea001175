"""Kinematics: hand-computed poses, inverse round trips, aiming, limits, demo feasibility."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.errors import LimitError
from controller.geometry.aiming import angle_mrad, intersect_plane, reflected_beam, source_direction
from controller.geometry.kinematics import (
    HeliostatKinematics,
    angles_from_normal,
    joint_rotation,
    normal_from_angles,
)

D = math.radians


@pytest.mark.parametrize("alpha, eps, expected", [
    (0.0, 0.0, [0, 0, 1]),                    # elevation 0 from zenith: facing up
    (0.0, 90.0, [0, -1, 0]),                  # facing south on the horizon
    (30.0, 90.0, [0.5, -math.sqrt(3) / 2, 0]),  # turned 30° towards east
    (0.0, 60.0, [0, -math.sqrt(3) / 2, 0.5]),  # 60° from zenith, southwards
    (90.0, 40.0, [1, 0, 0]),                  # azimuth joint at 90°: east whatever ε
])
def test_normal_hand_values(alpha, eps, expected):
    assert normal_from_angles(D(alpha), D(eps)) == pytest.approx(expected, abs=1e-12)
    assert joint_rotation(D(alpha), D(eps)) @ np.array([0, -1, 0]) == pytest.approx(expected, abs=1e-12)


def test_angles_from_normal_inverts():
    for a in np.linspace(-1.2, 1.2, 7):
        for e in np.linspace(-1.2, 1.5, 7):
            assert angles_from_normal(normal_from_angles(a, e)) == pytest.approx((a, e), abs=1e-12)


def test_steps_for_normal_round_trip(aa39):
    for az in (2000, 20000, 37654, 60000, 75000):
        for el in (3000, 25000, 50000, 68000):
            assert aa39.steps_for_normal(aa39.normal(az, el)) == (az, el)


def test_unreachable_normals_raise(aa39):
    # 135° from the zenith: beyond the elevation stroke (which ends at ~91°).
    with pytest.raises(LimitError, match="elevation axis"):
        aa39.steps_for_normal([0, -0.5, -0.5])
    # Facing due north is outside the azimuth joint's reach (|α| ≤ ~54°).
    with pytest.raises(LimitError, match="azimuth axis"):
        aa39.steps_for_normal([0.9, 0.0, 0.1])


def test_concentrator_translation_moves_mirror_behind_pivot(aa39):
    """ARTIST body frame: c = (0, 0.175, 0) is along −b, i.e. 0.175 m against the normal."""
    c = aa39.mirror_center(30000, 30000) - aa39.position
    assert c == pytest.approx(-0.175 * aa39.normal(30000, 30000), abs=1e-12)


def test_aim_hits_the_aim_point(aa39):
    sun = np.array([0.3, -0.6, 0.742])
    sun /= np.linalg.norm(sun)
    aim = aa39.position + np.array([-10.0, -28.0, 36.0])
    az, el = aa39.aim(sun, aim)
    spot = intersect_plane(aa39.mirror_center(az, el), reflected_beam(sun, aa39.normal(az, el)),
                           aim, [0, 1, 0])
    # One motor step is ~20 µrad of normal: at 47 m the beam lands within ~2 mm.
    assert np.linalg.norm(spot - aim) < 0.005
    # Ignoring the 0.175 m mirror offset would miss by more than the step quantisation.
    flat = dataclasses.replace(aa39, concentrator_translation=np.zeros(3))
    assert np.linalg.norm(np.array(flat.aim(sun, aim)) - (az, el)) > 5


def test_from_config_uses_soft_limits(demo_config):
    h = demo_config.heliostats[0]
    k = HeliostatKinematics.from_config(h)
    assert k.position == pytest.approx(h.position_enu_m)
    assert k.azimuth.min_steps == h.axes.azimuth.soft_limits.min_steps
    assert k.elevation.max_steps == h.axes.elevation.soft_limits.max_steps


@pytest.mark.parametrize("offset_m", [None, 30.0])
def test_demo_plant_is_feasible(demo_config, offset_m):
    """Every demo heliostat can put the lamp's beam on the target centre and on the three standby
    points (left, right, above; the configured offset and 30 m) with at least 5 % of each axis'
    soft range to spare."""
    cfg = demo_config
    lamp = cfg.light_source("lamp")
    centre = np.array(cfg.target().center_enu_m)
    off = cfg.calibration.standby_offset_m if offset_m is None else offset_m
    points = [centre, centre + (-off, 0, 0), centre + (off, 0, 0), centre + (0, 0, off)]
    for h in cfg.heliostats:
        k = HeliostatKinematics.from_config(h)
        s = source_direction(lamp, k.position)
        for p in points:
            az, el = k.aim(s, p)
            for act, steps in ((k.azimuth, az), (k.elevation, el)):
                margin = 0.05 * (act.max_steps - act.min_steps)
                assert act.min_steps + margin < steps < act.max_steps - margin, (h.id, p, act.name, steps)
            beam = reflected_beam(s, k.normal(az, el))
            assert angle_mrad(beam, p - k.mirror_center(az, el)) < 0.1


def test_aim_with_a_lamp_uses_the_moving_mirror_centre(aa39):
    """With c = 0.175 m the mirror centre moves with the pose, and with it the direction to a lamp
    61 m away; passing the lamp position makes the beam hit the aim point within step
    quantisation, while a direction taken from the pivot leaves a beam error of ~0.4 mrad."""
    lamp = aa39.position + np.array([-10.0, -25.0, 55.0])
    aim = aa39.position + np.array([-13.0, -28.0, 34.0])
    az, el = aa39.aim(None, aim, lamp_position=lamp)
    centre = aa39.mirror_center(az, el)
    sun_like = (lamp - centre) / np.linalg.norm(lamp - centre)
    beam = reflected_beam(sun_like, aa39.normal(az, el))
    assert angle_mrad(beam, aim - centre) < 0.1
    fixed = (lamp - aa39.position) / np.linalg.norm(lamp - aa39.position)
    az2, el2 = aa39.aim(fixed, aim)
    beam2 = reflected_beam((lamp - aa39.mirror_center(az2, el2)), aa39.normal(az2, el2))
    assert angle_mrad(beam2, aim - aa39.mirror_center(az2, el2)) > 0.2


@settings(max_examples=200, deadline=None)
@given(az=st.integers(0, 75308), el=st.integers(0, 68745))
def test_steps_normal_round_trip_whole_range(aa39, az, el):
    assert aa39.steps_for_normal(aa39.normal(az, el)) == (az, el)
