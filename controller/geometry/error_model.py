"""Tracking-error model of a two-axis heliostat and its least-squares fit.

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

For this mount (elevation first, about East) τ_N is the same rotation as Δε, so the two
cannot be told apart from pointing data; :func:`fit_tracking_errors` therefore holds τ_N at
its given value by default and its effect lands in Δε. A mirror tilt about the mirror's own
up axis is likewise Δα. The other six are identifiable when the measurements span a range of
both joint angles (the fit reports 1-σ uncertainties from the Jacobian, so a poor spread
shows up as large σ).

Measurements are (source direction, commanded steps, measured beam centroid on the target).
The measured normal is the bisector of the source direction and the direction from the mirror
centre to the centroid; the fit minimises the two tangential components of (n* − n_meas).

References
----------
.. [1] D. C. Khalsa, J. Yellowhair, et al., "CSP heliostat tracking error models", SolarPACES
   2011; and K. Stone, "Automatic heliostat track alignment method", US patent 4,564,275
   (1986): pedestal tilt, reference biases, axis non-orthogonality and canting terms.
.. [2] D. W. Marquardt, "An algorithm for least-squares estimation of nonlinear parameters",
   SIAM J. Appl. Math. 11(2), 431-441, 1963; covariance σ² (JᵀJ)⁻¹ at the optimum.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controller.errors import InputError
from controller.geometry.aiming import aim_normal, angle_mrad
from controller.geometry.kinematics import (
    BODY_NORMAL,
    HeliostatKinematics,
    angles_from_normal,
    rotation_e,
    rotation_n,
    rotation_u,
)
from controller.geometry.vectors import unit

PARAMETER_NAMES = ("az_offset", "el_offset", "tilt_north", "tilt_east", "base_yaw",
                   "non_orthogonality", "mirror_offset")
DEFAULT_FIT = tuple(n for n in PARAMETER_NAMES if n != "tilt_north")


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


@dataclass(frozen=True, eq=False)  # numpy fields
class Measurement:
    """One calibration sample, as in a PAINT record.

    ``source_dir``: unit ENU vector towards the light source; ``az_steps``/``el_steps``: the
    commanded motor steps; ``spot_enu``: measured beam centroid on the target, m ENU.
    """

    source_dir: np.ndarray
    az_steps: float
    el_steps: float
    spot_enu: np.ndarray


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_tracking_errors`.

    ``params``: fitted parameters (rad); ``sigma``: their 1-σ uncertainties (rad; 0 for
    parameters held fixed, inf when the data cannot determine them); ``residual_mrad``: per
    measurement, the angle between modelled and measured mirror normals, mrad;
    ``residual_mrad_rms``: its root mean square; ``fitted``: names of the fitted parameters.
    """

    params: TrackingErrorParams
    sigma: TrackingErrorParams
    residual_mrad_rms: float
    residual_mrad: np.ndarray
    fitted: tuple[str, ...]
    initial_residual_mrad_rms: float

    def to_dict(self) -> dict:
        return {"params": self.params.to_dict(), "sigma": self.sigma.to_dict(),
                "residual_mrad_rms": self.residual_mrad_rms,
                "residual_mrad": [float(r) for r in self.residual_mrad],
                "initial_residual_mrad_rms": self.initial_residual_mrad_rms, "fitted": list(self.fitted)}


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


def measured_normal(kin: HeliostatKinematics, m: Measurement) -> np.ndarray:
    """Normal implied by a measurement: bisector of the source direction and the direction from
    the mirror centre (at the commanded steps) to the measured centroid."""
    return aim_normal(m.source_dir, kin.mirror_center(m.az_steps, m.el_steps), m.spot_enu)


def _tangent_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to unit ``n`` (and to each other)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t1 = unit(np.cross(helper, n))
    return t1, np.cross(n, t1)


def fit_tracking_errors(kin: HeliostatKinematics, measurements: Sequence[Measurement],
                        fit: Sequence[str] = DEFAULT_FIT, initial: TrackingErrorParams | None = None,
                        noise_mrad: float | None = None) -> FitResult:
    """Least-squares fit of the tracking-error parameters to calibration measurements.

    Parameters
    ----------
    kin : HeliostatKinematics
        Nominal kinematics of the heliostat.
    measurements : sequence of Measurement
        At least ceil(len(fit) / 2) + 1 samples, spread over both joint angles.
    fit : sequence of str
        Names of the parameters to fit; the others keep their ``initial`` values. The default
        omits ``tilt_north`` (identical to ``el_offset`` for this mount, see module docs).
    initial : TrackingErrorParams, optional
        Starting point and values of the fixed parameters (default all zero).
    noise_mrad : float, optional
        Known 1-σ noise of each tangential normal component, mrad. If None, σ is estimated from
        the residual sum of squares, s² = SSR / (2m − p).

    Returns
    -------
    FitResult

    References: [2]_ (Levenberg-Marquardt; covariance s² (JᵀJ)⁻¹).
    """
    from scipy.optimize import least_squares

    unknown = [n for n in fit if n not in PARAMETER_NAMES]
    if unknown:
        raise InputError(f"fit_tracking_errors: unknown parameter {unknown[0]!r}")
    fit = tuple(n for n in PARAMETER_NAMES if n in fit)
    if len(measurements) == 0:
        raise InputError("fit_tracking_errors: no measurements")
    start = initial or TrackingErrorParams()
    idx = [PARAMETER_NAMES.index(n) for n in fit]
    angles = [kin.angles(m.az_steps, m.el_steps) for m in measurements]
    targets = [measured_normal(kin, m) for m in measurements]
    bases = [_tangent_basis(n) for n in targets]

    def params_of(x: np.ndarray) -> TrackingErrorParams:
        full = start.to_array()
        full[idx] = x
        return TrackingErrorParams.from_array(full)

    def residuals(x: np.ndarray) -> np.ndarray:
        p = params_of(x)
        out = np.empty(2 * len(measurements))
        for i, ((a, e), (t1, t2)) in enumerate(zip(angles, bases, strict=True)):
            n = actual_normal_from_angles(p, a, e)
            out[2 * i], out[2 * i + 1] = np.dot(n, t1), np.dot(n, t2)
        return out

    x0 = start.to_array()[idx]
    m_res, n_par = 2 * len(measurements), len(fit)
    method = "lm" if m_res >= n_par else "trf"
    sol = least_squares(residuals, x0, method=method, x_scale=1e-3, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    params = params_of(sol.x)
    dof = m_res - n_par
    if noise_mrad is not None:
        s2 = (noise_mrad * 1e-3) ** 2
    else:
        s2 = float(np.sum(sol.fun**2)) / dof if dof > 0 else np.inf
    sig = np.zeros(len(PARAMETER_NAMES))
    # A rank-deficient Jacobian (too few or badly spread samples) leaves some parameters
    # undetermined: report them as infinitely uncertain instead of inverting noise.
    if np.linalg.matrix_rank(sol.jac, tol=1e-9 * np.linalg.norm(sol.jac)) < n_par:
        sig[idx] = np.inf
    else:
        sig[idx] = np.sqrt(np.clip(np.diag(np.linalg.inv(sol.jac.T @ sol.jac)) * s2, 0.0, None))
    residual = np.array([float(angle_mrad(actual_normal_from_angles(params, a, e), t))
                         for (a, e), t in zip(angles, targets, strict=True)])
    initial_res = np.array([float(angle_mrad(actual_normal_from_angles(start, a, e), t))
                            for (a, e), t in zip(angles, targets, strict=True)])
    return FitResult(params, TrackingErrorParams.from_array(sig), float(np.sqrt(np.mean(residual**2))),
                     residual, fit, float(np.sqrt(np.mean(initial_res**2))))


def angles_for_normal_with_errors(params: TrackingErrorParams, desired_normal,
                                  max_iterations: int = 50, tol_rad: float = 1e-12) -> tuple[float, float]:
    """Nominal joint angles (α, ε), rad, whose *actual* normal (Eq. 1) is ``desired_normal``.

    Fixed-point iteration on the ideal inverse: (α, ε) += angles(desired) − angles(n*(α, ε)).
    The error rotation is small, so each pass shrinks the error by about its size in radians.
    """
    goal = np.array(angles_from_normal(desired_normal))
    x = goal.copy()
    for _ in range(max_iterations):
        step = goal - np.array(angles_from_normal(actual_normal_from_angles(params, *x)))
        x = x + step
        if np.max(np.abs(step)) < tol_rad:
            break
    return float(x[0]), float(x[1])


def steps_for_normal_with_errors(kin: HeliostatKinematics, params: TrackingErrorParams,
                                 desired_normal) -> tuple[int, int]:
    """Motor steps (az, el) that make the *actual* normal (with fitted errors) ``desired_normal``.

    Raises LimitError naming the axis when the compensated pose is outside the soft limits.
    """
    return kin.steps_for_angles(*angles_for_normal_with_errors(params, unit(desired_normal)))

