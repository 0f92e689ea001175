"""Rigid-body tracking errors: hand-computed single-parameter effects and storage."""

from __future__ import annotations

import math

import pytest

from controller.errors import InputError
from controller.geometry.error_model import (
    TrackingErrorParams,
    actual_normal,
    actual_normal_from_angles,
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
    """Both rotate about East for an elevation-first mount: pointing data see only their sum."""
    for alpha, eps in ((0.3, 0.5), (-0.9, 1.2), (0.0, 0.1)):
        assert actual_normal_from_angles(TrackingErrorParams(tilt_north=D), alpha, eps) == pytest.approx(
            actual_normal_from_angles(TrackingErrorParams(el_offset=-D), alpha, eps), abs=1e-15)


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
