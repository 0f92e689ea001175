"""The simulated plant's hidden heliostats — written independently of the controller's models.

Nothing here comes from ``controller.geometry`` or ``controller.calibration`` (a test checks
the imports): the forward kinematics below is its own, built from axis-angle rotations
(Rodrigues) about physical joint axes, and it contains effects that no controller model has.
The controller must find this heliostat out from what it measures, as it would a real one.

A heliostat (two linear actuators, elevation joint first, as the Jülich heliostats):

* **actuators** — law-of-cosines lever (ARTIST's linear actuator): stroke L = L₀ + k·s/inc
  with a stroke-scale error k = 1 + κ (lead-screw pitch tolerance), joint-side angle
  φ = acos((o² + r² − L²)/(2or)), joint angle θ = θ₀ ∓ (φ(L₀) − φ(L)); each of L₀, θ₀, o, r
  perturbed from the surveyed values;
* **pedestal** — tilted (two angles) and turned about the vertical (yaw);
* **joints** — the azimuth joint's axis is carried by the elevation joint and is off
  perpendicular by a small angle; the elevation joint turns about the pedestal's east axis,
  angle measured from the zenith (normal up at 0, facing south at α = 0);
* **mirror** — canting error (two small angles), centre displaced by the concentrator offset;
* **position** — the pivot is a few centimetres from its surveyed position;
* **gravity droop** — the elevation joint sags by g·sin ε (ε from the zenith: largest with the
  mirror vertical);
* **thermal drift** — each night both joint references move by a random step;
* **repeatability** — each move lands within a small random error (applied by the plant per
  move, :meth:`HeliostatTruth.normal` takes it as ``jitter``).

How a field is built (:class:`ErrorSpread`, 1-σ and means at the default ``scale`` 1, which
multiplies all of them) comes in two kinds (:data:`HIDDEN_ERRORS`):

* ``assumed`` (the default): the simulator's assumptions, chosen at or below the controller's
  prior σ and of the order of as-built tolerances of linear-actuator heliostats: pedestal tilt
  1.5 mrad, yaw 3 mrad, non-orthogonality 1 mrad, canting 1 mrad, actuator initial angle 3 mrad,
  initial stroke 1 mm, lever offset and pivot radius 0.5 mm, stroke scale 2·10⁻⁴, position 3 cm,
  droop 0.3 ± 0.1 mrad, nightly drift 0.1 mrad, repeatability 0.07 mrad per axis;
* ``paint-field``: what 16 real Jülich heliostats show (:data:`PAINT_FIELD`, its comment says
  how it was measured): references −10.6 ± 4.3 and −2.1 ± 3.0 mrad, yaw 28 ± 44 mrad, tilt east
  −1.9 ± 6.7 mrad, canting 10.1 ± 4.1 mrad, nightly drift 0.14 mrad, repeatability 0.25 mrad;
* ``first-light``: a new field as the Jülich heliostats were before their first calibration
  (:data:`FIRST_LIGHT`): the assumed as-built spread plus one whole-mirror error per heliostat,
  the error of one of the real field's heliostats at its first record, nominal vs measured
  normal (:data:`FIRST_LIGHT_NORMAL_MRAD`: median 35 mrad, mostly in azimuth, −21 mrad on
  average), outliers included (:data:`FIRST_LIGHT_OUTLIER`).

The numbers are copied here from those measurements; nothing of the controller computes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

EAST, NORTH, UP = np.eye(3)
FACING_SOUTH = -NORTH


def rodrigues(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix by ``angle_rad`` about the unit ``axis`` (right-handed):
    R = I + sin θ K + (1 − cos θ) K², K the cross-product matrix of the axis."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


@dataclass(frozen=True)
class ActuatorTruth:
    """One true linear actuator (lengths m, angles rad, ``increment`` steps per m)."""

    increment: float
    stroke0: float
    offset: float
    pivot_radius: float
    angle0: float
    clockwise: bool
    stroke_scale: float = 1.0

    def _phi(self, stroke: float) -> float:
        o, r = self.offset, self.pivot_radius
        return math.acos(max(-1.0, min(1.0, (o * o + r * r - stroke * stroke) / (2.0 * o * r))))

    def angle(self, steps: float) -> float:
        """True joint angle, rad, at motor ``steps``."""
        stroke = self.stroke0 + self.stroke_scale * float(steps) / self.increment
        turn = self._phi(self.stroke0) - self._phi(stroke)
        return self.angle0 + turn if self.clockwise else self.angle0 - turn


@dataclass(frozen=True, eq=False)  # numpy fields
class HeliostatTruth:
    """The hidden heliostat (module docstring). Angles rad, lengths m, ENU."""

    position: np.ndarray
    elevation: ActuatorTruth
    azimuth: ActuatorTruth
    pedestal: np.ndarray
    non_orthogonality: float
    canting: tuple[float, float]
    concentrator: np.ndarray
    droop: float
    drift_per_night: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    repeatability: float = 0.07e-3  # rad per axis and move (ErrorSpread.repeatability)

    def _drift(self, night: int) -> np.ndarray:
        if night <= 0 or not len(self.drift_per_night):
            return np.zeros(2)
        return self.drift_per_night[:min(night, len(self.drift_per_night))].sum(axis=0)

    def _frame(self, az_steps: float, el_steps: float, night: int, jitter) -> np.ndarray:
        d_el, d_az = self._drift(night)
        eps = self.elevation.angle(el_steps) + d_el
        eps += self.droop * math.sin(eps)
        alpha = self.azimuth.angle(az_steps) + d_az
        if jitter is not None:
            eps, alpha = eps + float(jitter[0]), alpha + float(jitter[1])
        return self.pedestal @ rodrigues(EAST, eps - math.pi / 2.0) @ rodrigues(self._joint_up, alpha)

    # The two constant rotations are computed once (the same products, so the same bits):
    # the plant asks for normals thousands of times a second.
    @cached_property
    def _joint_up(self) -> np.ndarray:
        return rodrigues(NORTH, self.non_orthogonality) @ UP

    @cached_property
    def _cant(self) -> np.ndarray:
        return rodrigues(EAST, self.canting[0]) @ rodrigues(UP, self.canting[1])

    def normal(self, az_steps: float, el_steps: float, night: int = 0, jitter=None) -> np.ndarray:
        """Unit ENU mirror normal at the given motor steps on ``night`` (0: the first)."""
        n = self._frame(az_steps, el_steps, night, jitter) @ self._cant @ FACING_SOUTH
        return n / np.linalg.norm(n)

    def mirror_center(self, az_steps: float, el_steps: float, night: int = 0) -> np.ndarray:
        """Centre of the mirror, m ENU."""
        return self.position + self._frame(az_steps, el_steps, night, None) @ self.concentrator


@dataclass(frozen=True)
class ErrorSpread:
    """How a field's heliostats are built: the mean and 1-σ of each hidden error at ``scale``
    1 (angles mrad, lengths mm). ``initial_angle`` and the other pairs are (elevation, azimuth),
    ``tilt`` (north, east), ``canting`` (about the mirror's east, about its up axis); ``droop``
    (mean, σ); ``drift_per_night`` the σ of each joint reference's step from one night to the
    next; ``repeatability`` the σ of each rod's landing error per move (per axis)."""

    initial_angle: tuple[float, float] = (3.0, 3.0)
    initial_angle_mean: tuple[float, float] = (0.0, 0.0)
    stroke: tuple[float, float] = (1.0, 1.0)
    stroke_mean: tuple[float, float] = (0.0, 0.0)
    lever_offset: float = 0.5
    pivot_radius: float = 0.5
    stroke_scale: float = 2e-4
    tilt: tuple[float, float] = (1.5, 1.5)
    tilt_mean: tuple[float, float] = (0.0, 0.0)
    yaw: float = 3.0
    yaw_mean: float = 0.0
    non_orthogonality: float = 1.0
    canting: tuple[float, float] = (1.0, 1.0)
    canting_mean: tuple[float, float] = (0.0, 0.0)
    position: float = 30.0
    droop: tuple[float, float] = (0.3, 0.1)
    drift_per_night: float = 0.1
    repeatability: float = 0.07
    # A whole-mirror error per heliostat drawn from this sample (empty: none), each (azimuth
    # error times the cosine of the elevation, elevation error) of the normal, mrad; one of
    # ``outlier[1]`` heliostats off by ``outlier[0]`` mrad in a random direction instead.
    normal_error_mrad: tuple[tuple[float, float], ...] = ()
    outlier: tuple[float, float] = (0.0, 0.0)


# The simulator's own assumptions (module docstring): at or below the controller's prior σ.
ASSUMED = ErrorSpread()

# What the 16 Jülich heliostats of PAINT show (tests/data/real/paint-field; docs/tracking-model.md,
# "The simulated plant learns from the real field"): each heliostat's tracking model fitted to
# all its records, then the mean and standard deviation over the heliostats whose fit identified
# the term. Elevation reference −10.6 ± 4.6 mrad (it holds the pedestal's north tilt, which no
# pointing data separate from it: that tilt keeps 1.5 mrad and the reference the rest), azimuth
# reference −2.1 ± 3.0, base yaw 28 ± 44, tilt east −1.9 ± 6.7, non-orthogonality 0 ± 0.8, mirror
# offset (canting about east) 10.1 ± 4.1, azimuth stroke 0.2 ± 0.4 mm. What the records do not
# identify (the elevation stroke, the lever, the position, droop) keeps the assumption. Drift:
# the references' random walk the fit uses on these records, 0.1 mrad per √day and 0.1 mrad
# between sessions, i.e. 0.14 mrad from one night to the next. Repeatability: a record scatters
# 0.38 mrad (normal, RMS) about the fit within its session; less the two spot methods' floor
# (0.15 mrad), 0.35 mrad, i.e. 0.25 mrad per axis.
PAINT_FIELD = ErrorSpread(
    initial_angle=(4.3, 3.0), initial_angle_mean=(-10.6, -2.1), stroke=(1.0, 0.4),
    stroke_mean=(0.0, 0.2),
    tilt=(1.5, 6.7), tilt_mean=(0.0, -1.9), yaw=44.0, yaw_mean=28.0, non_orthogonality=0.8,
    canting=(4.1, 1.0), canting_mean=(10.1, 0.0), drift_per_night=0.14, repeatability=0.25)

# The measured mirror normal (the sun's direction and the UTIS focal spot from the heliostat's
# surveyed position) less the nominal one (the heliostat's properties file: its kinematics at
# the record's motor steps) at the first record of each of the 16 Jülich heliostats of PAINT
# (tests/data/real/paint-field; tests/geometry/test_first_light_errors.py computes them again
# from the files), as (azimuth error × cos elevation, elevation error), mrad: angles median
# 34.8 mrad, quartiles 19.5 and 41.9 mrad; the azimuth errors −21 ± 41 mrad, elevation −2 ± 5.
FIRST_LIGHT_NORMAL_MRAD = (
    (-27.9, -16.3), (-35.4, -1.3), (11.8, -2.9), (-79.7, -0.7), (-2.4, 0.8), (34.1, -0.5), (-38.9, 1.5),
    (-35.5, -0.5), (21.7, -0.1), (12.9, 0.9), (-21.5, -2.3), (-40.7, -6.9), (43.5, -1.4), (-12.5, -1.5),
    (-92.7, 4.4), (-62.0, -6.6))
# The same measurement on 31 heliostats of that field (the 16 above among them) found one
# heliostat off by 1 rad (median 34, quartiles 16 and 55 mrad): one in 31 is drawn that far off.
FIRST_LIGHT_OUTLIER = (1000.0, 31.0)
# The rest as assumed, the drives' repeatability included: the real field's 0.25 mrad (PAINT_FIELD)
# is its records' scatter about a fit, the two spot methods' floor in it, not this plant's drives.
FIRST_LIGHT = ErrorSpread(normal_error_mrad=FIRST_LIGHT_NORMAL_MRAD, outlier=FIRST_LIGHT_OUTLIER)

HIDDEN_ERRORS = {"assumed": ASSUMED, "paint-field": PAINT_FIELD, "first-light": FIRST_LIGHT}


def draw_truth(position, elevation: dict, azimuth: dict, concentrator, rng: np.random.Generator, *,
               scale: float = 1.0, nights: int = 8, extra: dict | None = None,
               spread: ErrorSpread = ASSUMED, facing=None) -> HeliostatTruth:
    """A hidden heliostat about its surveyed description.

    ``elevation``/``azimuth``: surveyed actuator values (keys ``increment``,
    ``initial_stroke_length``, ``offset``, ``pivot_radius``, ``initial_angle``,
    ``clockwise_axis_movement``); ``position``: surveyed pivot, m ENU; ``concentrator``: body
    offset of the mirror centre, m. ``spread``: how the field is built (:class:`ErrorSpread`);
    ``scale`` multiplies every error (0: exactly as surveyed); ``extra`` adds an error case's
    own pointing (``az_offset``, ``el_offset``, ``tilt_east``, rad). A spread with a
    ``normal_error_mrad`` sample turns the pedestal, last, so that the normal along ``facing``
    (unit ENU, the mirror's nominal normal at work; default up) is off as one of its errors
    (:func:`whole_mirror_turn`)."""
    extra = extra or {}
    mrad = 1e-3 * scale
    mm = 1e-3 * scale
    sp = spread

    def actuator(a: dict, k: int, offset_extra: float) -> ActuatorTruth:
        # Drawn in this order, whatever the spread: a seed gives the same heliostats as before.
        stroke0 = float(a["initial_stroke_length"]) + rng.normal(sp.stroke_mean[k] * mm, sp.stroke[k] * mm)
        lever = float(a["offset"]) + rng.normal(0.0, sp.lever_offset * mm)
        radius = float(a["pivot_radius"]) + rng.normal(0.0, sp.pivot_radius * mm)
        error = rng.normal(sp.initial_angle_mean[k] * mrad, sp.initial_angle[k] * mrad)
        angle0 = float(a["initial_angle"]) + error + offset_extra
        pitch = 1.0 + rng.normal(0.0, sp.stroke_scale * scale)
        return ActuatorTruth(float(a["increment"]), stroke0, lever, radius, angle0,
                             bool(a["clockwise_axis_movement"]), pitch)

    el = actuator(elevation, 0, float(extra.get("el_offset", 0.0)))
    az = actuator(azimuth, 1, float(extra.get("az_offset", 0.0)))
    tilt_n, tilt_e = rng.normal(np.multiply(sp.tilt_mean, mrad), np.multiply(sp.tilt, mrad))
    tilt_e += float(extra.get("tilt_east", 0.0))
    pedestal = (rodrigues(UP, rng.normal(sp.yaw_mean * mrad, sp.yaw * mrad)) @ rodrigues(NORTH, tilt_e)
                @ rodrigues(EAST, -tilt_n))
    position = np.asarray(position, float) + rng.normal(0.0, sp.position * mm, 3)
    rest = (float(rng.normal(0.0, sp.non_orthogonality * mrad)),
            (float(rng.normal(sp.canting_mean[0] * mrad, sp.canting[0] * mrad)),
             float(rng.normal(sp.canting_mean[1] * mrad, sp.canting[1] * mrad))),
            float(rng.normal(*sp.droop)) * mrad, rng.normal(0.0, sp.drift_per_night * mrad, (nights, 2)))
    if sp.normal_error_mrad:
        pedestal = whole_mirror_turn(rng, sp, UP if facing is None else facing) @ pedestal
    return HeliostatTruth(
        position=position,
        elevation=el, azimuth=az, pedestal=pedestal, non_orthogonality=rest[0], canting=rest[1],
        concentrator=np.asarray(concentrator, float), droop=rest[2], drift_per_night=rest[3],
        repeatability=sp.repeatability * 1e-3)


def whole_mirror_turn(rng: np.random.Generator, sp: ErrorSpread, facing) -> np.ndarray:
    """The rotation (3, 3) of a whole-mirror error drawn from ``sp.normal_error_mrad``: a turn
    about the vertical by the azimuth error (over cos elevation of ``facing``), then about the
    horizontal axis across ``facing`` by the elevation error, so that a normal along ``facing``
    is off by (azimuth × cos elevation, elevation). With probability 1/``sp.outlier[1]`` instead a
    turn by ``sp.outlier[0]`` mrad about an axis across ``facing`` at a random bearing."""
    f = np.asarray(facing, float) / np.linalg.norm(facing)
    across = np.cross(UP, f) if np.linalg.norm(np.cross(UP, f)) > 1e-6 else EAST
    across = across / np.linalg.norm(across)
    d_az, d_el = np.asarray(sp.normal_error_mrad, float)[int(rng.integers(0, len(sp.normal_error_mrad)))]
    phi = float(rng.uniform(0.0, 2.0 * math.pi))
    if sp.outlier[1] > 0 and rng.uniform() < 1.0 / sp.outlier[1]:
        axis = math.cos(phi) * across + math.sin(phi) * np.cross(f, across)
        return rodrigues(axis, 1e-3 * sp.outlier[0])
    cos_el = max(math.sqrt(max(1.0 - float(f @ UP) ** 2, 0.0)), 0.1)
    # Azimuth runs clockwise from north (a turn about up by −angle); elevation up turns the
    # normal towards the zenith (about −across).
    return rodrigues(-across, 1e-3 * d_el) @ rodrigues(UP, -1e-3 * d_az / cos_el)


def hidden_truth(h, rng: np.random.Generator, scale: float, case=None,
                 spread: ErrorSpread = ASSUMED, facing=None) -> HeliostatTruth:
    """A hidden heliostat about the surveyed description of ``h`` (a configured heliostat:
    ``position_enu_m``, ``axes.elevation``/``axes.azimuth`` with the actuator fields,
    ``concentrator_translation_m``), with an
    error ``case``'s own pointing error (``case.params``: az_offset, el_offset, tilt_east, rad)
    added; ``facing``: :func:`draw_truth`. Duck-typed, so this module needs nothing of the
    controller."""
    def axis(a) -> dict:
        return {k: getattr(a, k) for k in ("increment", "initial_stroke_length", "offset", "pivot_radius",
                                            "initial_angle", "clockwise_axis_movement")}

    pointing = ("az_offset", "el_offset", "tilt_east")
    extra = {} if case is None else {k: getattr(case.params, k) for k in pointing}
    return draw_truth(h.position_enu_m, axis(h.axes.elevation), axis(h.axes.azimuth),
                      h.concentrator_translation_m, rng, scale=scale, extra=extra, spread=spread,
                      facing=facing)
