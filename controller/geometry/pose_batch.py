"""The tracking model of one heliostat evaluated for many poses and many parameter sets at once.

The same equations as :mod:`controller.geometry.model.tracking` (actuators Eq. 1-3 of
:mod:`controller.geometry.actuators`, the error rotation R* of
:mod:`controller.geometry.error_model` Eq. 1, the mirror centre c* = x₀ + Δx + R* c of Eq. 4),
written as array operations: parameter sets along a leading axis P, poses along an axis K.
Instead of building R* as a product of seven matrices, each body vector (the normal b and the
concentrator translation c) is turned by the seven rotations in turn, right to left,

    R* v = R_u(γ) R_n(τ_E) R_e(−τ_N) R_e(ε + Δε − π/2) R_n(δ) R_u(α + Δα) R_e(μ) v,

which is what the planner, the model's daytime prediction and the spot prediction evaluate
thousands of times per heliostat (forward-difference Jacobians over the 14 terms, candidate
geometries, sun positions). A pose out of reach is NaN (no actuator triangle) or masked
(:func:`aim_steps`), never an exception.

Units and conventions: those of the scalar modules (SI inside: rad, m; ENU; motor steps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from controller.geometry.actuators import LinearActuator
from controller.geometry.kinematics import BODY_NORMAL, HeliostatKinematics
from controller.geometry.model.tracking import NAMES
from controller.geometry.vectors import norm

_I = {n: i for i, n in enumerate(NAMES)}
STEP_SI = 1e-6  # forward-difference step of the Jacobians (design._STEP): linear range, far above rounding


def joint_angle(act: LinearActuator, steps, d_stroke0=0.0, d_radius=0.0) -> np.ndarray:
    """θ(s) of actuators Eq. 1-3 for the actuator with its initial stroke and pivot radius moved
    by ``d_stroke0``, ``d_radius`` (m; the model's actuator terms), broadcast against ``steps``;
    NaN where the stroke leaves the actuator triangle."""
    l0 = act.initial_stroke_length + np.asarray(d_stroke0, float)
    r = act.pivot_radius + np.asarray(d_radius, float)
    o = act.offset

    def phi(stroke):
        c = (o * o + r * r - stroke * stroke) / (2.0 * o * r)
        return np.arccos(np.where(np.abs(c) <= 1.0, c, np.nan))

    sign = np.where(act.clockwise_axis_movement, 1.0, -1.0)
    return act.initial_angle + sign * (phi(l0) - phi(np.asarray(steps, float) / act.increment + l0))


def joint_steps(act: LinearActuator, angle, d_stroke0=0.0, d_radius=0.0) -> np.ndarray:
    """Unrounded motor steps giving joint angle ``angle`` (rad): the inverse of
    :func:`joint_angle`; NaN where no actuator triangle reaches it."""
    l0 = act.initial_stroke_length + np.asarray(d_stroke0, float)
    r = act.pivot_radius + np.asarray(d_radius, float)
    o = act.offset
    phi0 = np.arccos((o * o + r * r - l0 * l0) / (2.0 * o * r))
    sign = np.where(act.clockwise_axis_movement, 1.0, -1.0)
    phi = phi0 - sign * (np.asarray(angle, float) - act.initial_angle)
    phi = np.where((phi >= 0.0) & (phi <= np.pi), phi, np.nan)
    return (np.sqrt(o * o + r * r - 2.0 * o * r * np.cos(phi)) - l0) * act.increment


def turn(values: np.ndarray, alpha, eps, body: np.ndarray) -> np.ndarray:
    """R* ``body`` (module equation) for model ``values`` (..., 14) SI at nominal joint angles
    α, ε (rad; broadcast against values[..., 0]); ``body`` (3,) a body-frame vector, or several
    along leading axes that broadcast against the rest. A right-handed turn by θ about East (0),
    North (1) or Up (2) maps the plane's components (y, z), (z, x) or (x, y) to
    (c·y − s·z, s·y + c·z) and alike, c = cos θ, s = sin θ; the three components are held apart,
    so that no array is assembled until the last turn (issue 42: a third less per call)."""
    v = np.asarray(values, float)

    def p(name):
        return v[..., _I[name]]

    body = np.asarray(body, float)
    xyz = [body[..., 0], body[..., 1], body[..., 2]]
    # R_e(−τ_N) R_e(ε + Δε − π/2): two turns about East are one
    for angle, axis in ((p("mirror_offset"), 0), (np.asarray(alpha, float) + p("az_offset"), 2),
                        (p("non_orthogonality"), 1),
                        (np.asarray(eps, float) + p("el_offset") - np.pi / 2.0 - p("tilt_north"), 0),
                        (p("tilt_east"), 1), (p("base_yaw"), 2)):
        c, s = np.cos(angle), np.sin(angle)
        i, j = ((1, 2), (2, 0), (0, 1))[axis]  # the plane turned: y→z about E, z→x about N, x→y about U
        xyz[i], xyz[j] = c * xyz[i] - s * xyz[j], s * xyz[i] + c * xyz[j]
    shape = np.broadcast_shapes(v.shape[:-1], body.shape[:-1], *(np.shape(a) for a in xyz))
    out = np.empty((*shape, 3))
    for k in range(3):
        out[..., k] = xyz[k]
    return out


def angles(kin: HeliostatKinematics, values: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nominal joint angles (α, ε), rad, at ``steps`` (..., 2) with the actuator terms of
    ``values`` (..., 14), broadcast."""
    v = np.asarray(values, float)
    s = np.asarray(steps, float)
    a = joint_angle(kin.azimuth, s[..., 0], v[..., _I["az_stroke0"]], v[..., _I["az_pivot_radius"]])
    e = joint_angle(kin.elevation, s[..., 1], v[..., _I["el_stroke0"]], v[..., _I["el_pivot_radius"]])
    return a, e


def normal_and_center(kin: HeliostatKinematics, values: np.ndarray,
                      steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Actual unit normal n* = R* b and mirror centre c* = x₀ + Δx + R* c (m ENU) at motor
    ``steps`` (..., 2) for model ``values`` (..., 14) SI, broadcast (P parameter sets at K poses:
    values (P, 1, 14), steps (K, 2)): shapes (..., 3)."""
    v = np.asarray(values, float)
    if v.ndim == 1 and np.shape(steps) == (1, 2):  # one pose of one model: a beam-safety check
        return _one_pose(kin, v, *np.asarray(steps, float)[0])
    a, e = angles(kin, v, steps)
    pos = v[..., [_I["position_e"], _I["position_n"], _I["position_u"]]]
    if kin.concentrator_translation.any():  # both body vectors turned at once: half the array calls
        body = np.stack(np.broadcast_arrays(BODY_NORMAL, np.asarray(kin.concentrator_translation, float)))
        lead = max(v.ndim - 1, np.ndim(a), body.ndim - 2)  # the result's axes: (2, *lead, 3)
        n, c = turn(v, a, e, body.reshape(2, *(1,) * (lead - body.ndim + 2), *body.shape[1:]))
    else:
        n = turn(v, a, e, BODY_NORMAL)
        c = np.zeros_like(n)
    return n, kin.position + pos + c


def _one_pose(kin: HeliostatKinematics, v: np.ndarray, az: float, el: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`normal_and_center` at one pose of one model, in floats: the same equations
    (actuators Eq. 1-3, the module equation) without the arrays' per-call cost, for the
    thousands of single-pose checks of a night (a slot handed over at each status poll of a
    park, a standby pose's person zones). Shapes (1, 3)."""
    p = v.tolist()

    def joint(act: LinearActuator, steps: float, d_stroke0: float, d_radius: float) -> float:
        l0, r, o = act.initial_stroke_length + d_stroke0, act.pivot_radius + d_radius, act.offset

        def phi(stroke: float) -> float:
            c = (o * o + r * r - stroke * stroke) / (2.0 * o * r)
            return math.acos(c) if abs(c) <= 1.0 else math.nan
        sign = 1.0 if act.clockwise_axis_movement else -1.0
        return act.initial_angle + sign * (phi(l0) - phi(steps / act.increment + l0))

    i = _I
    a = joint(kin.azimuth, az, p[i["az_stroke0"]], p[i["az_pivot_radius"]])
    e = joint(kin.elevation, el, p[i["el_stroke0"]], p[i["el_pivot_radius"]])
    bodies = [BODY_NORMAL.tolist(), kin.concentrator_translation.tolist()]
    for angle, axis in ((p[i["mirror_offset"]], 0), (a + p[i["az_offset"]], 2),
                        (p[i["non_orthogonality"]], 1), (e + p[i["el_offset"]] - math.pi / 2.0, 0),
                        (-p[i["tilt_north"]], 0), (p[i["tilt_east"]], 1), (p[i["base_yaw"]], 2)):
        c, s = math.cos(angle), math.sin(angle)
        j, k = ((1, 2), (2, 0), (0, 1))[axis]  # as in turn
        for b in bodies:
            b[j], b[k] = c * b[j] - s * b[k], s * b[j] + c * b[k]
    pos = (p[i["position_e"]], p[i["position_n"]], p[i["position_u"]])
    return (np.array([bodies[0]]),
            np.array([[kin.position[m] + pos[m] + bodies[1][m] for m in range(3)]]))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / norm(v)


def angles_for_normals(values: np.ndarray, normals: np.ndarray, max_iterations: int = 50,
                       tol_rad: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Nominal joint angles (α, ε) whose actual normal (Eq. 1 of the error model) is each of
    ``normals`` (..., 3), for model ``values`` (..., 14), broadcast: the fixed-point iteration of
    :func:`controller.geometry.error_model.angles_for_normal_with_errors`, for all at once."""
    n = _unit(np.asarray(normals, float))
    goal = np.stack([np.arcsin(np.clip(n[..., 0], -1.0, 1.0)), np.arctan2(-n[..., 1], n[..., 2])], axis=-1)
    x = goal.copy()
    for _ in range(max_iterations):
        m = turn(values, x[..., 0], x[..., 1], BODY_NORMAL)
        got = np.stack([np.arcsin(np.clip(m[..., 0], -1.0, 1.0)), np.arctan2(-m[..., 1], m[..., 2])], axis=-1)
        step = goal - got
        x = x + step
        if not (np.abs(step) >= tol_rad).any():
            break
    return x[..., 0], x[..., 1]


def steps_for_normals(kin: HeliostatKinematics, values: np.ndarray,
                      normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whole motor steps (..., 2) whose actual normal is each of ``normals`` (..., 3) with model
    ``values`` (..., 14), broadcast, and whether each is inside the soft limits (...,) — the
    batched :func:`controller.geometry.model.tracking.steps_for_normal`."""
    v = np.asarray(values, float)
    a, e = angles_for_normals(v, normals)
    sa = joint_steps(kin.azimuth, a, v[..., _I["az_stroke0"]], v[..., _I["az_pivot_radius"]])
    se = joint_steps(kin.elevation, e, v[..., _I["el_stroke0"]], v[..., _I["el_pivot_radius"]])
    ok = np.isfinite(sa) & np.isfinite(se)
    s = np.stack([np.where(ok, np.round(sa), 0.0), np.where(ok, np.round(se), 0.0)], axis=-1)
    ok &= ((s[..., 0] >= kin.azimuth.min_steps) & (s[..., 0] <= kin.azimuth.max_steps)
           & (s[..., 1] >= kin.elevation.min_steps) & (s[..., 1] <= kin.elevation.max_steps))
    return s.astype(np.int64), ok


def aim_steps(kin: HeliostatKinematics, values: np.ndarray, points: np.ndarray, *, source_dirs=None,
              lamp=None, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Motor steps (..., K, 2) that reflect the source onto each of ``points`` (..., K, 3) m ENU
    with model ``values`` ((14,), or (..., 1, 14) for a stack of heliostats, :class:`KinStack`),
    and a mask (..., K) of those in reach — the batched
    :func:`controller.geometry.model.tracking.model_aim`: the bisector from the mirror centre,
    re-evaluated ``iterations`` times as the centre moves with the pose. The source is a lamp
    at ``lamp`` ((3,) or (..., K, 3) m ENU; its direction taken from the mirror centre) or the
    directions ``source_dirs`` (..., K, 3), unit ENU towards the source. A pose out of reach in
    any pass is out of reach (as the scalar function raises)."""
    v = np.asarray(values, float)
    pts = np.asarray(points, float)
    if pts.ndim == 1:
        pts = pts[None]
    pos = v[..., [_I["position_e"], _I["position_n"], _I["position_u"]]]
    center = np.broadcast_to(kin.position + pos + turn(v, 0.0, 0.0, kin.concentrator_translation), pts.shape)
    ok = np.ones(pts.shape[:-1], bool)
    steps = np.zeros((*pts.shape[:-1], 2), np.int64)
    fixed = None if lamp is not None else _unit(np.asarray(source_dirs, float))
    for _ in range(iterations):
        src = _unit(np.asarray(lamp, float) - center) if lamp is not None else fixed
        steps, fine = steps_for_normals(kin, v, _unit(src + _unit(pts - center)))
        ok &= fine
        _, center = normal_and_center(kin, v, steps)
        ok &= np.all(np.isfinite(center), axis=-1)
        center = np.where(ok[..., None], center, kin.position)
    return steps, ok


def perturbed(values: np.ndarray, step: float = STEP_SI) -> np.ndarray:
    """(..., p + 1, p) parameter sets: ``values`` (..., p) and, row i + 1, ``values`` with term i
    moved by ``step`` — the evaluation points of a forward-difference Jacobian."""
    v = np.asarray(values, float)[..., None, :]
    return np.concatenate([v, v + step * np.eye(v.shape[-1])], axis=-2)


def forward_jacobian(f: np.ndarray, step: float = STEP_SI, axis: int = 0) -> np.ndarray:
    """∂f/∂p from ``f`` evaluated at :func:`perturbed` points along ``axis`` (p + 1 of them),
    with the values' last axis m: (..., m, p), the other axes kept in order."""
    f = np.moveaxis(np.asarray(f), axis, 0)
    return np.moveaxis((f[1:] - f[0]) / step, 0, -1)


@dataclass(frozen=True, eq=False)  # numpy fields
class AxisStack:
    """One axis of H heliostats' actuators: the :class:`LinearActuator` fields as arrays (H,)."""

    increment: np.ndarray
    initial_stroke_length: np.ndarray
    offset: np.ndarray
    pivot_radius: np.ndarray
    initial_angle: np.ndarray
    clockwise_axis_movement: np.ndarray
    min_steps: np.ndarray
    max_steps: np.ndarray

    @classmethod
    def of(cls, axes: list[LinearActuator]) -> AxisStack:
        return cls(*(np.array([getattr(a, f.name) for a in axes]) for f in fields(cls)))

    def shaped(self, ndim: int) -> AxisStack:
        return AxisStack(*(getattr(self, f.name).reshape((-1,) + (1,) * (ndim - 1)) for f in fields(self)))


@dataclass(frozen=True, eq=False)  # numpy fields
class KinStack:
    """The kinematics of H heliostats as arrays, for the functions above to evaluate a chunk of a
    field at once: pass ``kin.shaped(d)`` with the heliostat on the first of d leading axes
    (e.g. d = 2 for steps (H, K, 2), d = 3 for values (H, P, 1, 14) at steps (H, 1, K, 2))."""

    position: np.ndarray  # (H, 3)
    azimuth: AxisStack
    elevation: AxisStack
    concentrator_translation: np.ndarray  # (H, 3)

    @classmethod
    def of(cls, kins: list[HeliostatKinematics]) -> KinStack:
        return cls(np.array([k.position for k in kins], float), AxisStack.of([k.azimuth for k in kins]),
                   AxisStack.of([k.elevation for k in kins]),
                   np.array([k.concentrator_translation for k in kins], float))

    def shaped(self, ndim: int) -> KinStack:
        pad = (1,) * (ndim - 1)
        return KinStack(self.position.reshape((-1, *pad, 3)), self.azimuth.shaped(ndim),
                        self.elevation.shaped(ndim), self.concentrator_translation.reshape((-1, *pad, 3)))
