"""Rigid-body tracking errors of a two-axis heliostat.

The ideal pose R(α, ε) = R_e(ε − π/2) R_u(α) (kinematics, Eq. 1) becomes, with small
mechanical errors,

    R* = R_u(γ) R_n(τ_E) R_e(−τ_N) · R_e(ε + Δε − π/2) · R_n(δ) · R_u(α + Δα) · R_e(μ),   (1)

and the actual normal is n* = R* b, b = (0, −1, 0) (body frame). The parameters (radians):

====================  =====================================================================
``az_offset`` Δα       azimuth reference (encoder zero) offset, added to the azimuth angle
``el_offset`` Δε       elevation reference (encoder zero) offset, added to the elevation angle
``tilt_north`` τ_N     pedestal tilted towards north (its top moves north), about East
``tilt_east`` τ_E      pedestal tilted towards east (its top moves east), about North
``base_yaw`` γ         pedestal turned about Up (elevation axis not exactly east-west)
``non_orthogonality`` δ  azimuth axis not perpendicular to the elevation axis
``mirror_offset`` μ    mirror (canting) normal tilted about the mirror's east axis
====================  =====================================================================

For this mount (elevation first, about East) τ_N is the same rotation as Δε, so pointing
data see only their sum; the fit (:mod:`controller.geometry.model.fit`) keeps both with their
priors and its covariance carries the degeneracy. A mirror tilt about the mirror's own up axis
is likewise Δα. These are the rigid-body terms of the tracking model
(:mod:`controller.geometry.model.tracking`), which adds the actuators' terms.

References
----------
.. [1] D. C. Khalsa, J. Yellowhair, et al., "CSP heliostat tracking error models", SolarPACES
   2011; and K. Stone, "Automatic heliostat track alignment method", US patent 4,564,275
   (1986): pedestal tilt, reference biases, axis non-orthogonality and canting terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.kinematics import (
    BODY_NORMAL,
    HeliostatKinematics,
    angles_from_normal,
    rotation_e,
    rotation_n,
    rotation_u,
)

PARAMETER_NAMES = ("az_offset", "el_offset", "tilt_north", "tilt_east", "base_yaw",
                   "non_orthogonality", "mirror_offset")


@dataclass(frozen=True)
class TrackingErrorParams:
    """Tracking-error parameters, radians (see the module table). All zero = ideal heliostat."""

    az_offset: float = 0.0
    el_offset: float = 0.0
    tilt_north: float = 0.0
    tilt_east: float = 0.0
    base_yaw: float = 0.0
    non_orthogonality: float = 0.0
    mirror_offset: float = 0.0

    def to_array(self) -> np.ndarray:
        return np.array([getattr(self, n) for n in PARAMETER_NAMES])

    @classmethod
    def from_array(cls, values) -> TrackingErrorParams:
        return cls(*(float(v) for v in values))

    def to_dict(self) -> dict[str, float]:
        """For storage: ``{"<name>_mrad": value}`` in milliradians."""
        return {f"{n}_mrad": 1e3 * getattr(self, n) for n in PARAMETER_NAMES}

    @classmethod
    def from_dict(cls, data: dict) -> TrackingErrorParams:
        """Inverse of :meth:`to_dict`; missing keys are 0, unknown keys raise InputError."""
        known = {f"{n}_mrad" for n in PARAMETER_NAMES}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"tracking-error parameters: unknown key {unknown[0]!r} "
                             f"(known: {', '.join(sorted(known))})")
        return cls(**{n: 1e-3 * float(data.get(f"{n}_mrad", 0.0)) for n in PARAMETER_NAMES})


def error_rotation(params: TrackingErrorParams, alpha_rad: float, eps_rad: float) -> np.ndarray:
    """R* of Eq. (1): body frame -> ENU for joint angles α, ε (rad) with errors ``params``."""
    p = params
    base = rotation_u(p.base_yaw) @ rotation_n(p.tilt_east) @ rotation_e(-p.tilt_north)
    return (base @ rotation_e(eps_rad + p.el_offset - np.pi / 2.0) @ rotation_n(p.non_orthogonality)
            @ rotation_u(alpha_rad + p.az_offset) @ rotation_e(p.mirror_offset))


def actual_normal_from_angles(params: TrackingErrorParams, alpha_rad: float, eps_rad: float) -> np.ndarray:
    """Actual unit ENU normal n* = R* b (Eq. 1) for nominal joint angles α, ε in rad."""
    return error_rotation(params, alpha_rad, eps_rad) @ BODY_NORMAL


def actual_normal(kin: HeliostatKinematics, params: TrackingErrorParams, az_steps: float,
                  el_steps: float) -> np.ndarray:
    """Actual unit ENU mirror normal when ``az_steps``/``el_steps`` are commanded (Eq. 1)."""
    return actual_normal_from_angles(params, *kin.angles(az_steps, el_steps))


def angles_for_normal_with_errors(params: TrackingErrorParams, desired_normal,
                                  max_iterations: int = 50, tol_rad: float = 1e-12) -> tuple[float, float]:
    """Nominal joint angles (α, ε), rad, whose *actual* normal (Eq. 1) is ``desired_normal``.

    Fixed-point iteration on the ideal inverse: (α, ε) += angles(desired) − angles(n*(α, ε)).
    The error rotation is small, so each pass shrinks the error by about its size in radians.
    The rotations of Eq. (1) that do not move with the joints are multiplied once, and each
    pass turns R_e(μ) b = (0, −cos μ, −sin μ) through the rest in floats: the controller
    solves poses thousands of times a night (aims, standby points, slots, lamp changes).
    """
    p = params
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = (
        rotation_u(p.base_yaw) @ rotation_n(p.tilt_east) @ rotation_e(-p.tilt_north)).tolist()
    cm, sm = math.cos(p.mirror_offset), math.sin(p.mirror_offset)
    cd, sd = math.cos(p.non_orthogonality), math.sin(p.non_orthogonality)

    def angles_of_actual(alpha: float, eps: float) -> tuple[float, float]:
        a, e = alpha + p.az_offset, eps + p.el_offset - math.pi / 2.0
        wx, wy, wz = math.sin(a) * cm, -math.cos(a) * cm, -sm  # R_u(α + Δα) R_e(μ) b
        wx, wz = cd * wx + sd * wz, cd * wz - sd * wx  # R_n(δ)
        ce, se = math.cos(e), math.sin(e)
        wy, wz = ce * wy - se * wz, se * wy + ce * wz  # R_e(ε + Δε − π/2)
        nx, ny, nz = (b00 * wx + b01 * wy + b02 * wz, b10 * wx + b11 * wy + b12 * wz,
                      b20 * wx + b21 * wy + b22 * wz)
        sin_a = nx / math.sqrt(nx * nx + ny * ny + nz * nz)
        return math.asin(min(1.0, max(-1.0, sin_a))), math.atan2(-ny, nz)

    ga, ge = angles_from_normal(desired_normal)
    x = (ga, ge)
    for _ in range(max_iterations):
        a, e = angles_of_actual(*x)
        step = (ga - a, ge - e)
        x = (x[0] + step[0], x[1] + step[1])
        if max(abs(step[0]), abs(step[1])) < tol_rad:
            break
    return float(x[0]), float(x[1])
