"""The heliostat tracking model: nominal kinematics plus rigid-body and linear-actuator terms.

A heliostat's pointing, from motor steps (s_az, s_el) to the actual ENU mirror normal, is

    θ_j = A_j(s_j; L₀,j + ΔL₀,j, r_j + Δr_j)          joint angle of actuator j (actuators, Eq. 1-3)
    n*  = R*(θ_az, θ_el; rigid terms) b              rigid-body error rotation (error_model, Eq. 1)

The actuator terms change the step → angle map itself: ΔL₀ (initial stroke length) and Δr
(pivot radius) bend and stretch it, so their effect varies over the stroke. An actuator's
initial-angle error Δθ₀ adds to its joint angle everywhere (Eq. 3), which is exactly the
joint's reference offset: ``az_offset``/``el_offset`` *are* the actuators' Δθ₀ (one term each,
not two that no data could tell apart). Terms, with the prior σ the fit regularises towards
(:data:`TERMS`; as-built tolerances of linear-actuator heliostats, the rotations widened to
what the fits of 16 real Jülich heliostats show — base yaw −35 to +98 mrad, mirror offset 0
to 13 mrad, tilt east −10 to +6 mrad; docs/tracking-model.md, "On real heliostats"):

=====================  ======  =========  ==================================================
name                   unit    prior σ    meaning
=====================  ======  =========  ==================================================
``az_offset``          mrad    15         azimuth joint reference = Δθ₀ of its actuator
``el_offset``          mrad    15         elevation joint reference = Δθ₀ of its actuator
``tilt_north``         mrad    3          pedestal top towards north (about East)
``tilt_east``          mrad    5          pedestal top towards east (about North)
``base_yaw``           mrad    50         pedestal turned about Up (heading of the bolt circle)
``non_orthogonality``  mrad    3          azimuth axis not perpendicular to the elevation axis
``mirror_offset``      mrad    15         mirror/canting normal tilted about the mirror's east
``az_stroke0``         mm      2          azimuth actuator initial stroke length ΔL₀
``el_stroke0``         mm      2          elevation actuator initial stroke length ΔL₀
``az_pivot_radius``    mm      1          azimuth actuator pivot radius Δr
``el_pivot_radius``    mm      1          elevation actuator pivot radius Δr
``position_e``         mm      30         pivot east of its surveyed position
``position_n``         mm      30         pivot north of its surveyed position
``position_u``         mm      30         pivot above its surveyed position
=====================  ======  =========  ==================================================

The position terms Δx move the mirror centre, c* = x₀ + Δx + R* c (Eq. 4): a few
centimetres of survey error turn the direction to a target 50 m away by about 1 mrad, and
since a translation moves a beam spot by itself while a rotation moves it by 2 × distance,
spots seen from several light directions separate the two. Held at their surveyed values,
not fitted: the joint and concentrator translations (their errors are millimetres).

Conventions: those of :mod:`controller.geometry.kinematics` (elevation joint about East from
the zenith, azimuth joint about the carried Up axis, mirror facing south at α = 0; PAINT/ARTIST
sign of the actuators). Parameters are SI inside (rad, m) and mrad/mm at the edges
(:meth:`TrackingModel.to_dict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controller.errors import InputError
from controller.geometry.aiming import aim_normal, intersect_plane, reflected_beam
from controller.geometry.error_model import (
    PARAMETER_NAMES as RIGID_NAMES,
)
from controller.geometry.error_model import (
    TrackingErrorParams,
    angles_for_normal_with_errors,
    error_rotation,
)
from controller.geometry.kinematics import BODY_NORMAL, HeliostatKinematics
from controller.geometry.vectors import unit


@dataclass(frozen=True)
class Term:
    """One model term: ``name``, display ``unit`` (mrad or mm; SI = value × 1e-3), prior 1-σ
    in that unit, and a one-line meaning."""

    name: str
    unit: str
    prior_sigma: float
    meaning: str

    @property
    def key(self) -> str:
        return f"{self.name}_{self.unit}"


TERMS: tuple[Term, ...] = (
    Term("az_offset", "mrad", 15.0, "azimuth joint reference (actuator initial angle)"),
    Term("el_offset", "mrad", 15.0, "elevation joint reference (actuator initial angle)"),
    Term("tilt_north", "mrad", 3.0, "pedestal tilt towards north"),
    Term("tilt_east", "mrad", 5.0, "pedestal tilt towards east"),
    Term("base_yaw", "mrad", 50.0, "pedestal yaw about up"),
    Term("non_orthogonality", "mrad", 3.0, "azimuth axis not perpendicular to the elevation axis"),
    Term("mirror_offset", "mrad", 15.0, "mirror normal tilted about the mirror's east axis"),
    Term("az_stroke0", "mm", 2.0, "azimuth actuator initial stroke length"),
    Term("el_stroke0", "mm", 2.0, "elevation actuator initial stroke length"),
    Term("az_pivot_radius", "mm", 1.0, "azimuth actuator pivot radius"),
    Term("el_pivot_radius", "mm", 1.0, "elevation actuator pivot radius"),
    Term("position_e", "mm", 30.0, "pivot east of its surveyed position"),
    Term("position_n", "mm", 30.0, "pivot north of its surveyed position"),
    Term("position_u", "mm", 30.0, "pivot above its surveyed position"),
)
NAMES = tuple(t.name for t in TERMS)
PRIOR_SIGMA_SI = np.array([t.prior_sigma * 1e-3 for t in TERMS])
_KEYS = {t.key: i for i, t in enumerate(TERMS)}
_RIGID = np.array([NAMES.index(n) for n in RIGID_NAMES])
_POSITION = np.array([NAMES.index(n) for n in ("position_e", "position_n", "position_u")])


@dataclass(frozen=True, eq=False)  # numpy field
class TrackingModel:
    """Values of :data:`TERMS`, SI (rad, m), in that order. All zero = the nominal heliostat."""

    values: np.ndarray

    @classmethod
    def zero(cls) -> TrackingModel:
        return cls(np.zeros(len(TERMS)))

    def rigid(self) -> TrackingErrorParams:
        return TrackingErrorParams.from_array(self.values[_RIGID])

    def position_offset(self) -> np.ndarray:
        """Δx of Eq. (4), m ENU."""
        return self.values[_POSITION]

    def to_dict(self) -> dict[str, float]:
        """``{"<name>_<unit>": value}`` in mrad / mm (the stored and printed form)."""
        return {t.key: 1e3 * float(v) for t, v in zip(TERMS, self.values, strict=True)}

    @classmethod
    def from_dict(cls, data: dict, what: str = "tracking model") -> TrackingModel:
        """Inverse of :meth:`to_dict`. Missing terms are 0 (records of older, smaller models
        load unchanged); an unknown key or a non-finite value raises InputError naming it."""
        values = np.zeros(len(TERMS))
        for key, v in data.items():
            if key not in _KEYS:
                raise InputError(f"{what}: unknown term {key!r} (known: {', '.join(_KEYS)})")
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"{what}: {key} must be a finite number, got {v!r}")
            values[_KEYS[key]] = 1e-3 * float(v)
        return cls(values)


# Not a term of the model: the 1-σ per night of the random walk of both joint references
# (thermal drift), given with the terms' prior σ since it is a prior too (:func:`drift_sigma`).
DRIFT_KEY = "drift_mrad"


def prior_sigma(overrides: dict[str, float] | None = None, what: str = "prior_sigma",
                base: np.ndarray | None = None) -> np.ndarray:
    """Prior 1-σ of every term, SI: ``base`` (default: the documented σ) with ``overrides``
    (``{key: σ}`` in the key's unit) applied (:data:`DRIFT_KEY` is no term and is skipped).
    InputError naming an unknown key."""
    sigma = (PRIOR_SIGMA_SI if base is None else np.asarray(base, float)).copy()
    for key, v in (overrides or {}).items():
        if key == DRIFT_KEY:
            continue
        if key not in _KEYS:
            raise InputError(f"{what}: unknown term {key!r} (known: {', '.join([*_KEYS, DRIFT_KEY])})")
        sigma[_KEYS[key]] = 1e-3 * float(v)
    return sigma


def drift_sigma(overrides: dict[str, float] | None = None) -> float:
    """1-σ (rad) per night of the joint references' random walk, ``overrides[DRIFT_KEY]`` (mrad);
    0 when not given (the references do not drift)."""
    return 1e-3 * float((overrides or {}).get(DRIFT_KEY, 0.0))


def actuated(kin: HeliostatKinematics, model: TrackingModel) -> HeliostatKinematics:
    """``kin`` with the model's actuator terms applied (ΔL₀ and Δr of each actuator)."""
    v = dict(zip(NAMES, model.values, strict=True))
    az = replace(kin.azimuth, initial_stroke_length=kin.azimuth.initial_stroke_length + v["az_stroke0"],
                 pivot_radius=kin.azimuth.pivot_radius + v["az_pivot_radius"])
    el = replace(kin.elevation, initial_stroke_length=kin.elevation.initial_stroke_length + v["el_stroke0"],
                 pivot_radius=kin.elevation.pivot_radius + v["el_pivot_radius"])
    return replace(kin, azimuth=az, elevation=el)


def poses(kin: HeliostatKinematics, model: TrackingModel, steps) -> list[np.ndarray]:
    """The actual body-to-ENU rotation R* (Eq. 1) at each (az_steps, el_steps) of ``steps``:
    the model's actuators and rigid terms evaluated once for all of them."""
    ak, rigid = actuated(kin, model), model.rigid()
    return [error_rotation(rigid, *ak.angles(az, el)) for az, el in steps]


def model_normal(kin: HeliostatKinematics, model: TrackingModel, az_steps: float,
                 el_steps: float) -> np.ndarray:
    """Actual unit ENU mirror normal at the given motor steps (module equations)."""
    return poses(kin, model, [(az_steps, el_steps)])[0] @ BODY_NORMAL


def model_mirror_center(kin: HeliostatKinematics, model: TrackingModel, az_steps: float,
                        el_steps: float) -> np.ndarray:
    """Centre of the reflecting surface, m ENU: surveyed pivot + Δx + R* c (Eq. 4; c the
    concentrator translation)."""
    rot = poses(kin, model, [(az_steps, el_steps)])[0]
    return kin.position + model.position_offset() + rot @ kin.concentrator_translation


def implied_normal(kin: HeliostatKinematics, model: TrackingModel, az_steps: float, el_steps: float,
                   source_dir, spot, source_pos=None) -> np.ndarray:
    """The normal a beam spot implies: bisector of the source direction and the direction from
    the model's mirror centre to ``spot`` (m ENU). For a lamp at ``source_pos`` (m ENU) the
    source direction is taken from that centre; otherwise ``source_dir`` (unit ENU, the sun)."""
    return bisector_normal(model_mirror_center(kin, model, az_steps, el_steps), source_dir, spot, source_pos)


def bisector_normal(center: np.ndarray, source_dir, spot, source_pos=None) -> np.ndarray:
    """Bisector of the source direction (``source_dir``, or from ``center`` towards the lamp at
    ``source_pos``) and the direction from ``center`` to ``spot`` (all m ENU)."""
    src = source_dir if source_pos is None else unit(np.asarray(source_pos, float) - center)
    return aim_normal(src, center, spot)


def steps_for_normal(kin: HeliostatKinematics, model: TrackingModel, desired_normal) -> tuple[int, int]:
    """Whole motor steps whose *actual* normal is ``desired_normal`` (ENU). LimitError naming
    the axis when the pose is outside the soft limits."""
    return _steps_for_normal(actuated(kin, model), model.rigid(), desired_normal)


def _steps_for_normal(actuated_kin: HeliostatKinematics, rigid: TrackingErrorParams,
                      desired_normal) -> tuple[int, int]:
    """:func:`steps_for_normal` with the model unpacked (:func:`actuated`, ``TrackingModel.rigid``)."""
    return actuated_kin.steps_for_angles(*angles_for_normal_with_errors(rigid, unit(desired_normal)))


def model_aim(kin: HeliostatKinematics, model: TrackingModel, source_dir, point, *,
              lamp_position=None, iterations: int = 3) -> tuple[int, int]:
    """Motor steps that reflect light from ``source_dir`` (unit ENU, towards the source) onto
    ``point`` (m ENU) with the model: the bisector from the mirror centre (which moves with the
    pose, so it is re-evaluated ``iterations`` times; each pass shrinks the error by
    |c|/distance). For a lamp pass ``lamp_position`` (m ENU) and the source direction is taken
    from the mirror centre. LimitError when out of reach."""
    point = np.asarray(point, float)
    ak, rigid, pivot = actuated(kin, model), model.rigid(), kin.position + model.position_offset()
    center = pivot + error_rotation(rigid, 0.0, 0.0) @ kin.concentrator_translation
    steps = (0, 0)
    for _ in range(iterations):  # the model unpacked once, not per pass
        if lamp_position is not None:
            source_dir = unit(np.asarray(lamp_position, float) - center)
        steps = _steps_for_normal(ak, rigid, aim_normal(source_dir, center, point))
        center = pivot + error_rotation(rigid, *ak.angles(*steps)) @ kin.concentrator_translation
    return steps


def model_spot(kin: HeliostatKinematics, model: TrackingModel, az_steps: float, el_steps: float, source_dir,
               plane_point, plane_normal) -> np.ndarray:
    """Where the reflected central ray (source ``source_dir``, unit ENU towards the source) meets
    the plane through ``plane_point`` with ``plane_normal``, m ENU, at the given steps."""
    n = model_normal(kin, model, az_steps, el_steps)
    origin = model_mirror_center(kin, model, az_steps, el_steps)
    return intersect_plane(origin, reflected_beam(source_dir, n), plane_point, plane_normal)
