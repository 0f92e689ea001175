"""The tracking model: hand-checked effect of each kind of term, storage, aiming with the model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.errors import InputError, LimitError
from controller.geometry.aiming import angle_mrad, reflected_beam
from controller.geometry.kinematics import normal_from_angles
from controller.geometry.model.tracking import (
    NAMES,
    PRIOR_SIGMA_SI,
    TERMS,
    TrackingModel,
    actuated,
    model_aim,
    model_mirror_center,
    model_normal,
    model_spot,
    prior_sigma,
    steps_for_normal,
)
from controller.geometry.vectors import azel_to_vector, unit

D = 1e-3  # 1 mrad, or 1 mm for the actuator terms (SI values)
POSES = ((12000, 9000), (37000, 30000), (65000, 52000))  # (az, el) steps across the AA39 range


def with_terms(**terms: float) -> TrackingModel:
    """A model with the named terms set (SI) and all others zero."""
    v = np.zeros(len(TERMS))
    for name, value in terms.items():
        v[NAMES.index(name)] = value
    return TrackingModel(v)


def lever_joint_angle(act, steps: float, d_stroke0: float = 0.0, d_radius: float = 0.0) -> float:
    """The actuator law written out by hand (law of cosines, stroke linear in steps, angle from
    the initial one, sign by the axis direction), with ΔL₀ and Δr applied."""
    o, r = act.offset, act.pivot_radius + d_radius
    l0 = act.initial_stroke_length + d_stroke0

    def phi(length: float) -> float:
        return math.acos((o * o + r * r - length * length) / (2.0 * o * r))

    turn = phi(l0) - phi(l0 + steps / act.increment)
    return act.initial_angle + turn if act.clockwise_axis_movement else act.initial_angle - turn


def test_zero_model_is_the_nominal_kinematics(aa39):
    zero = TrackingModel.zero()
    for az, el in POSES:
        assert model_normal(aa39, zero, az, el) == pytest.approx(aa39.normal(az, el), abs=1e-15)
        assert model_mirror_center(aa39, zero, az, el) == pytest.approx(aa39.mirror_center(az, el), abs=1e-12)


def test_reference_offsets_add_to_the_joint_angles(aa39):
    for az, el in POSES:
        alpha, eps = aa39.angles(az, el)
        assert model_normal(aa39, with_terms(az_offset=D), az, el) == pytest.approx(
            normal_from_angles(alpha + D, eps), abs=1e-14)
        assert model_normal(aa39, with_terms(el_offset=-2 * D), az, el) == pytest.approx(
            normal_from_angles(alpha, eps - 2 * D), abs=1e-14)


def test_tilt_north_is_the_same_rotation_as_minus_el_offset(aa39):
    """Elevation-first mount: a pedestal tilt towards north turns the mirror about East exactly
    as an elevation reference error does, so no pointing data can separate the two."""
    for az, el in POSES:
        assert model_normal(aa39, with_terms(tilt_north=D), az, el) == pytest.approx(
            model_normal(aa39, with_terms(el_offset=-D), az, el), abs=1e-14)


@pytest.mark.parametrize("axis", ["az", "el"])
def test_stroke_term_bends_the_step_to_angle_map(aa39, axis):
    """ΔL₀ goes into the law of cosines, so its effect on the joint angle is not a constant
    offset: it differs between a short and a long stroke (unlike az_offset/el_offset)."""
    act = aa39.azimuth if axis == "az" else aa39.elevation
    model = with_terms(**{f"{axis}_stroke0": 2 * D})
    delta = []
    for steps in (2000, 60000):
        got = actuated(aa39, model).angles(steps, steps)[0 if axis == "az" else 1]
        assert got == pytest.approx(lever_joint_angle(act, steps, d_stroke0=2 * D), abs=1e-12)
        delta.append(got - lever_joint_angle(act, steps))
    # 2 mm of initial stroke on a ~0.33 m lever: several mrad, changing by > 1 mrad over the stroke.
    assert 1e-3 < max(abs(d) for d in delta) < 2e-2
    assert abs(delta[0] - delta[1]) > 1e-3, delta


@pytest.mark.parametrize("axis", ["az", "el"])
def test_pivot_radius_term_bends_the_step_to_angle_map(aa39, axis):
    act = aa39.azimuth if axis == "az" else aa39.elevation
    model = with_terms(**{f"{axis}_pivot_radius": D})
    delta = []
    for steps in (2000, 60000):
        got = actuated(aa39, model).angles(steps, steps)[0 if axis == "az" else 1]
        assert got == pytest.approx(lever_joint_angle(act, steps, d_radius=D), abs=1e-12)
        delta.append(got - lever_joint_angle(act, steps))
    assert abs(delta[0] - delta[1]) > 2e-4, delta  # not an offset: it grows along the stroke
    # The other axis does not move.
    other = 1 if axis == "az" else 0
    assert actuated(aa39, model).angles(30000, 30000)[other] == pytest.approx(
        aa39.angles(30000, 30000)[other], abs=1e-15)


def test_position_terms_move_the_mirror_centre_not_the_normal(aa39):
    model = with_terms(position_e=0.03, position_n=-0.02, position_u=0.01)  # 3 cm, −2 cm, 1 cm
    for az, el in POSES:
        assert model_mirror_center(aa39, model, az, el) == pytest.approx(
            aa39.mirror_center(az, el) + np.array([0.03, -0.02, 0.01]), abs=1e-12)
        assert model_normal(aa39, model, az, el) == pytest.approx(aa39.normal(az, el), abs=1e-15)


def test_to_dict_round_trip_in_display_units():
    rng = np.random.default_rng(1)
    model = TrackingModel(rng.normal(0.0, 1.0, len(TERMS)) * PRIOR_SIGMA_SI)
    d = model.to_dict()
    assert list(d) == [f"{t.name}_{t.unit}" for t in TERMS]
    assert d["az_offset_mrad"] == pytest.approx(1e3 * model.values[0])
    assert d["az_stroke0_mm"] == pytest.approx(1e3 * model.values[NAMES.index("az_stroke0")])
    assert TrackingModel.from_dict(d).values == pytest.approx(model.values, abs=1e-15)
    # Older, smaller models load: missing terms are zero.
    partial = TrackingModel.from_dict({"az_offset_mrad": 2.5})
    assert partial.values[0] == pytest.approx(2.5e-3) and not np.any(partial.values[1:])


@pytest.mark.parametrize("data, match", [
    ({"spin_mrad": 1.0}, "unknown term 'spin_mrad'"),
    ({"az_offset": 1.0}, "unknown term 'az_offset'"),  # the unit is part of the key
    ({"az_offset_mrad": float("nan")}, "az_offset_mrad must be a finite number"),
    ({"el_stroke0_mm": float("inf")}, "el_stroke0_mm must be a finite number"),
    ({"base_yaw_mrad": "3"}, "base_yaw_mrad must be a finite number"),
    ({"base_yaw_mrad": True}, "base_yaw_mrad must be a finite number"),
])
def test_from_dict_rejects_bad_terms_naming_them(data, match):
    with pytest.raises(InputError, match=match):
        TrackingModel.from_dict(data, "MODEL.json: terms")


def test_prior_sigma_overrides():
    sigma = prior_sigma({"az_offset_mrad": 1.0, "el_pivot_radius_mm": 0.25})
    assert sigma[0] == pytest.approx(1e-3)
    assert sigma[NAMES.index("el_pivot_radius")] == pytest.approx(0.25e-3)
    untouched = [i for i, n in enumerate(NAMES) if n not in ("az_offset", "el_pivot_radius")]
    assert sigma[untouched] == pytest.approx(PRIOR_SIGMA_SI[untouched])
    assert prior_sigma() == pytest.approx(PRIOR_SIGMA_SI)
    assert prior_sigma()[NAMES.index("az_offset")] == pytest.approx(15e-3)  # documented default
    with pytest.raises(InputError, match="calibration.model.prior_sigma: unknown term 'yaw_mrad'"):
        prior_sigma({"yaw_mrad": 1.0}, "calibration.model.prior_sigma")


SOME_MODEL = with_terms(az_offset=-12 * D, el_offset=3 * D, tilt_east=1.5 * D, base_yaw=4 * D,
                        non_orthogonality=-1 * D, mirror_offset=2 * D, az_stroke0=1 * D, el_stroke0=-1 * D,
                        az_pivot_radius=0.5 * D, el_pivot_radius=-0.5 * D, position_e=20 * D,
                        position_u=-10 * D)


# Sun directions from the south-east to the south-west, lighting AA39's front.
SUNS = [azel_to_vector(az, el) for az, el in ((120, 30), (160, 55), (200, 45), (240, 20))]


@pytest.fixture()
def target(aa39_records):
    return aa39_records[0]["plane_point"], aa39_records[0]["plane_normal"]


def test_model_aim_puts_the_models_beam_on_the_aim_point(aa39, target):
    point, _ = target
    for sun in SUNS:
        az, el = model_aim(aa39, SOME_MODEL, sun, point)
        beam = reflected_beam(sun, model_normal(aa39, SOME_MODEL, az, el))
        wanted = unit(point - model_mirror_center(aa39, SOME_MODEL, az, el))
        assert angle_mrad(beam, wanted) < 0.05  # whole motor steps: ~0.02 mrad per step
        # The nominal steps miss by the model's ~10 mrad: the model is what moved the beam.
        nominal = reflected_beam(sun, model_normal(aa39, SOME_MODEL, *aa39.aim(sun, point)))
        assert angle_mrad(nominal, wanted) > 5.0


def test_model_aim_compensates_an_azimuth_offset_by_the_step_slope(aa39, target):
    """With only az_offset = +5 mrad the azimuth joint must turn 5 mrad less: the steps move
    by −5 mrad / (dθ/ds) and the elevation steps stay (to a step)."""
    point, _ = target
    sun = azel_to_vector(160, 55)
    az0, el0 = model_aim(aa39, TrackingModel.zero(), sun, point)
    az1, el1 = model_aim(aa39, with_terms(az_offset=5 * D), sun, point)
    expected = -5e-3 / aa39.azimuth.angle_per_step(az0)
    assert az1 - az0 == pytest.approx(expected, abs=2.0)
    assert abs(el1 - el0) <= 1


def test_model_aim_with_a_lamp(aa39, target):
    point, _ = target
    lamp = point + np.array([3.0, 0.0, 6.0])  # a lamp on the tower, near the target
    az, el = model_aim(aa39, SOME_MODEL, None, point, lamp_position=lamp)
    c = model_mirror_center(aa39, SOME_MODEL, az, el)
    beam = reflected_beam(unit(lamp - c), model_normal(aa39, SOME_MODEL, az, el))
    assert angle_mrad(beam, unit(point - c)) < 0.05


def test_model_spot_lands_where_model_aim_aimed(aa39, target):
    point, normal = target
    for sun in SUNS:
        az, el = model_aim(aa39, SOME_MODEL, sun, point)
        spot = model_spot(aa39, SOME_MODEL, az, el, sun, point, normal)
        assert abs(float((spot - point) @ normal)) < 1e-9  # on the target plane
        distance = np.linalg.norm(point - aa39.position)
        assert np.linalg.norm(spot - point) < 0.05e-3 * distance * 1.5
        # The same steps with the nominal kinematics land metres away.
        assert np.linalg.norm(aa39.spot(az, el, sun, point, normal) - point) > 0.3


def test_steps_for_normal_outside_the_soft_limits_names_the_axis(aa39):
    with pytest.raises(LimitError, match="axis"):
        steps_for_normal(aa39, SOME_MODEL, np.array([0.0, 1.0, 0.05]))  # facing north, beyond reach
