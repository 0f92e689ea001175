"""Tracking-error model: hand-computed single-parameter effects, fit recovery, compensation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from controller.errors import InputError
from controller.geometry.aiming import angle_mrad, reflected_beam
from controller.geometry.error_model import (
    DEFAULT_FIT,
    Measurement,
    TrackingErrorParams,
    actual_normal,
    actual_normal_from_angles,
    fit_tracking_errors,
    steps_for_normal_with_errors,
)
from controller.geometry.kinematics import normal_from_angles

D = 1e-3  # 1 mrad
HALF_PI = math.pi / 2


def test_zero_parameters_give_the_nominal_normal(aa39):
    for az, el in ((1000, 2000), (37000, 30000), (70000, 60000)):
        nominal = aa39.normal(az, el)
        assert actual_normal(aa39, TrackingErrorParams(), az, el) == pytest.approx(nominal, abs=1e-15)


@pytest.mark.parametrize("alpha, eps", [(0.3, 0.5), (-0.7, 1.1)])
def test_reference_offsets_add_to_the_joint_angles(alpha, eps):
    assert actual_normal_from_angles(TrackingErrorParams(az_offset=D), alpha, eps) == pytest.approx(
        normal_from_angles(alpha + D, eps), abs=1e-15)
    assert actual_normal_from_angles(TrackingErrorParams(el_offset=D), alpha, eps) == pytest.approx(
        normal_from_angles(alpha, eps + D), abs=1e-15)


def test_tilt_north_is_indistinguishable_from_el_offset():
    """Both rotate about East for an elevation-first mount, hence DEFAULT_FIT omits tilt_north."""
    for alpha, eps in ((0.3, 0.5), (-0.9, 1.2), (0.0, 0.1)):
        assert actual_normal_from_angles(TrackingErrorParams(tilt_north=D), alpha, eps) == pytest.approx(
            actual_normal_from_angles(TrackingErrorParams(el_offset=-D), alpha, eps), abs=1e-15)
    assert "tilt_north" not in DEFAULT_FIT and len(DEFAULT_FIT) == 6


def test_single_parameter_effects_hand_values():
    s, c = math.sin(D), math.cos(D)
    # Mirror facing up: a pedestal tilted east tips the normal east; a mirror offset tips it south.
    assert actual_normal_from_angles(TrackingErrorParams(tilt_east=D), 0.0, 0.0) == pytest.approx([s, 0, c])
    assert actual_normal_from_angles(TrackingErrorParams(mirror_offset=D), 0.0, 0.0) == pytest.approx(
        [0, -s, c])
    # Mirror facing south on the horizon: base yaw turns it east.
    assert actual_normal_from_angles(TrackingErrorParams(base_yaw=D), 0.0, HALF_PI) == pytest.approx(
        [s, -c, 0])
    # Non-orthogonality does nothing at α = 0 and tips an east-facing normal down by δ at α = 90°.
    assert actual_normal_from_angles(TrackingErrorParams(non_orthogonality=D), 0.0, 0.7) == pytest.approx(
        normal_from_angles(0.0, 0.7), abs=1e-15)
    assert actual_normal_from_angles(TrackingErrorParams(non_orthogonality=D), HALF_PI, HALF_PI) == (
        pytest.approx([c, 0, -s]))


def test_storage_dict_is_in_mrad():
    p = TrackingErrorParams(az_offset=0.001, mirror_offset=-0.0025)
    d = p.to_dict()
    assert d["az_offset_mrad"] == pytest.approx(1.0) and d["mirror_offset_mrad"] == pytest.approx(-2.5)
    assert TrackingErrorParams.from_dict(d).to_array() == pytest.approx(p.to_array(), abs=1e-15)
    with pytest.raises(InputError, match="unknown key 'tilt_mrad'"):
        TrackingErrorParams.from_dict({"tilt_mrad": 1.0})


TRUE = TrackingErrorParams(az_offset=2.0 * D, el_offset=-1.5 * D, tilt_east=1.0 * D, base_yaw=-0.8 * D,
                           non_orthogonality=1.2 * D, mirror_offset=0.7 * D)


def _synthetic(kin, params, n, spot_noise_m, rng) -> list[Measurement]:
    """Measurements over the AA39 working range: random pose and sun, spot 50 m down the beam."""
    out = []
    while len(out) < n:
        az = rng.uniform(8000, 70000)
        el = rng.uniform(5000, 45000)
        sun = rng.normal(size=3)
        sun[2] = abs(sun[2]) + 0.3
        sun /= np.linalg.norm(sun)
        normal = actual_normal(kin, params, az, el)
        if np.dot(sun, normal) < 0.3:  # the sun must light the mirror's front at < 72° incidence
            continue
        beam = reflected_beam(sun, normal)
        spot = kin.mirror_center(az, el) + 50.0 * beam + rng.normal(scale=spot_noise_m, size=3)
        out.append(Measurement(sun, az, el, spot))
    return out


def test_fit_recovers_known_parameters(aa39):
    rng = np.random.default_rng(20240601)
    ms = _synthetic(aa39, TRUE, 60, 0.01, rng)  # 1 cm spot noise at 50 m: 0.1-0.2 mrad of normal
    fit = fit_tracking_errors(aa39, ms)
    assert fit.fitted == DEFAULT_FIT
    assert fit.initial_residual_mrad_rms > 2.0
    assert fit.residual_mrad_rms < 0.25
    for name in DEFAULT_FIT:
        got, sigma, true = getattr(fit.params, name), getattr(fit.sigma, name), getattr(TRUE, name)
        assert 0 < sigma < 0.3 * D, name  # the spread of poses determines every fitted parameter
        assert abs(got - true) < 4 * sigma, (name, got, true, sigma)
    assert fit.params.tilt_north == 0.0 and fit.sigma.tilt_north == 0.0


def test_fit_with_known_noise_and_too_few_samples(aa39):
    rng = np.random.default_rng(3)
    ms = _synthetic(aa39, TRUE, 2, 0.0, rng)
    fit = fit_tracking_errors(aa39, ms)  # 4 equations, 6 unknowns: undetermined
    assert all(math.isinf(getattr(fit.sigma, n)) for n in DEFAULT_FIT)
    assert fit.residual_mrad_rms < 1e-6  # it still matches the data it has
    two = fit_tracking_errors(aa39, _synthetic(aa39, TRUE, 12, 0.0, rng), fit=("az_offset", "el_offset"),
                              noise_mrad=0.1)
    assert two.fitted == ("az_offset", "el_offset") and two.sigma.az_offset > 0
    with pytest.raises(InputError, match="unknown parameter 'spin'"):
        fit_tracking_errors(aa39, ms, fit=("spin",))


def test_compensated_steps_point_the_actual_normal(aa39):
    desired = np.array([0.35, -0.45, 0.82])
    desired /= np.linalg.norm(desired)
    az, el = steps_for_normal_with_errors(aa39, TRUE, desired)
    # Residual is the motor-step quantisation only: about 20 µrad per step.
    assert angle_mrad(actual_normal(aa39, TRUE, az, el), desired) < 0.05
    naive = aa39.steps_for_normal(desired)
    assert angle_mrad(actual_normal(aa39, TRUE, *naive), desired) > 1.5


def test_fit_then_compensate_closes_the_loop(aa39):
    rng = np.random.default_rng(11)
    fit = fit_tracking_errors(aa39, _synthetic(aa39, TRUE, 40, 0.005, rng))
    desired = np.array([-0.2, -0.5, 0.84])
    desired /= np.linalg.norm(desired)
    az, el = steps_for_normal_with_errors(aa39, fit.params, desired)
    assert angle_mrad(actual_normal(aa39, TRUE, az, el), desired) < 0.15
    flat = dataclasses.replace(aa39, concentrator_translation=np.zeros(3))
    assert steps_for_normal_with_errors(flat, fit.params, desired) == (az, el)  # the normal ignores c
