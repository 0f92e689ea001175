"""Linear actuators: hand-computed triangles, AA39 values, round trips, soft limits."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.errors import LimitError
from controller.geometry.actuators import LinearActuator, lever_angle, stroke_from_steps


def _toy(clockwise: bool) -> LinearActuator:
    # 0.3-0.4-0.5 m right triangle at step 0: φ0 = 90°; 1000 steps per metre.
    return LinearActuator("toy", 1000.0, 0.5, 0.3, 0.4, 0.2, clockwise, 0, 400, 0, 400)


def test_law_of_cosines_hand_values():
    assert lever_angle(0.5, 0.3, 0.4) == pytest.approx(math.pi / 2)
    assert lever_angle(math.sqrt(0.37), 0.3, 0.4) == pytest.approx(2 * math.pi / 3)  # 0.37 = .25 + .12
    with pytest.raises(ValueError, match="triangle"):
        lever_angle(0.8, 0.3, 0.4)


@pytest.mark.parametrize("clockwise, sign", [(False, 1.0), (True, -1.0)])
def test_angle_from_steps_hand_values(clockwise, sign):
    act = _toy(clockwise)
    steps = (math.sqrt(0.37) - 0.5) * 1000.0  # stroke for φ = 120°, 108.276 steps
    assert act.stroke(0) == pytest.approx(0.5)
    assert act.angle(0) == pytest.approx(0.2)
    # φ grows by 30°: a counter-clockwise axis opens by 30°, a clockwise one closes by 30°.
    assert act.angle(steps) == pytest.approx(0.2 + sign * math.radians(30))
    assert act.steps_float(0.2 + sign * math.radians(30)) == pytest.approx(steps)


def test_aa39_actuators(aa39):
    el, az = aa39.elevation, aa39.azimuth
    assert el.angle(0) == pytest.approx(0.039009536) and az.angle(0) == pytest.approx(0.943922248)
    assert stroke_from_steps(154166.6667, 154166.6667, 0.077412795) == pytest.approx(1.077412795)
    # Elevation (counter-clockwise) rises with steps, azimuth (clockwise) falls.
    assert el.angle(60000) > el.angle(10000) and az.angle(60000) < az.angle(10000)
    # Full elevation stroke, by hand: L = 0.077413 -> 0.523328 m, o = 0.335308, r = 0.338095:
    # φ = arccos((o² + r² − L²)/(2or)) goes 13.194° -> 101.998°, a swing of 88.80°.
    assert math.degrees(el.angle(el.max_increment) - el.angle(0)) == pytest.approx(88.8, abs=0.1)


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_round_trip_full_step_range(aa39, data):
    for act in (aa39.azimuth, aa39.elevation):
        s = data.draw(st.integers(act.min_increment, act.max_increment))
        assert act.steps(float(act.angle(s))) == s
        assert act.steps_float(act.angle(s)) == pytest.approx(s, abs=1e-6)


@pytest.mark.parametrize("axis", ["azimuth", "elevation"])
def test_round_trip_endpoints_and_every_1000_steps(aa39, axis):
    act = getattr(aa39, axis)
    for s in [*range(act.min_increment, act.max_increment, 1000), act.max_increment]:
        assert act.steps(float(act.angle(s))) == s


def test_soft_limits_name_axis_and_value(demo_config):
    axis = demo_config.heliostats[0].axes.elevation
    act = LinearActuator.from_config("elevation", axis)
    assert (act.min_steps, act.max_steps) == (axis.soft_limits.min_steps, axis.soft_limits.max_steps)
    with pytest.raises(LimitError,
                       match=r"elevation axis: .* needs 100 steps, outside the soft limits \[500, "):
        act.steps(float(act.angle(100)))
    with pytest.raises(LimitError, match="cannot be reached"):
        act.steps(10.0)
