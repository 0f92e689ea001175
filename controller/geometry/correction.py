"""Correction of the axes from a measured beam offset on the target (Jacobian step).

The beam-centroid position on the target plane is a function s(α, ε) of the joint angles
(kinematics, Eq. 2, reflection and ray/plane intersection). For a measured offset
Δs = s_measured − s_wanted (m, ENU, in the target plane), the joint-angle change that removes it
to first order is the least-squares solution of

    J · Δθ = −Δs,    J = ∂s/∂(α, ε)  (3 × 2, m/rad, central differences),      (1)

Δθ = −J⁺ Δs (Moore-Penrose pseudo-inverse). The angle changes are turned into motor steps
through the exact actuator inverse (actuators, Eq. 1-3) at the current position.

References
----------
.. [1] C. T. Kelley, "Solving Nonlinear Equations with Newton's Method", SIAM 2003, Ch. 1-2:
   Gauss-Newton step with a finite-difference Jacobian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.geometry.aiming import intersect_plane, reflected_beam
from controller.geometry.kinematics import HeliostatKinematics, normal_from_angles

_H = 1e-6  # rad: central-difference step; spot error O(h²·distance) ≪ 1 µm


@dataclass(frozen=True)
class Correction:
    """Axis changes that move the beam back by the measured offset.

    ``daz_deg``/``del_deg``: joint-angle changes, degrees; ``daz_steps``/``del_steps``: the same
    as whole motor steps to add to the current command; ``residual_m``: the part of the offset
    the two axes cannot remove (off the target plane / numerical), m.
    """

    daz_deg: float
    del_deg: float
    daz_steps: int
    del_steps: int
    residual_m: float = 0.0

    def to_dict(self) -> dict:
        return {"daz_deg": self.daz_deg, "del_deg": self.del_deg, "daz_steps": self.daz_steps,
                "del_steps": self.del_steps, "residual_m": self.residual_m}


def _plane(target) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(target, "center_enu_m"):
        return np.asarray(target.center_enu_m, dtype=float), np.asarray(target.normal, dtype=float)
    point, normal = target
    return np.asarray(point, dtype=float), np.asarray(normal, dtype=float)


def spot_jacobian(alpha_rad: float, eps_rad: float, source_dir, heliostat_pos, target) -> np.ndarray:
    """∂s/∂(α, ε) of Eq. (1), m/rad, shape (3, 2), by central differences."""
    point, normal = _plane(target)

    def spot(a: float, e: float) -> np.ndarray:
        beam = reflected_beam(source_dir, normal_from_angles(a, e))
        return intersect_plane(heliostat_pos, beam, point, normal)

    return np.column_stack([(spot(alpha_rad + _H, eps_rad) - spot(alpha_rad - _H, eps_rad)) / (2 * _H),
                            (spot(alpha_rad, eps_rad + _H) - spot(alpha_rad, eps_rad - _H)) / (2 * _H)])


def correction_from_offset(kin: HeliostatKinematics, az_steps: float, el_steps: float, source_dir,
                           heliostat_pos, target, offset_enu) -> Correction:
    """Axis correction for a measured beam offset on the target (Eq. 1).

    Parameters
    ----------
    kin : HeliostatKinematics
    az_steps, el_steps : float
        The commanded motor steps while the offset was measured.
    source_dir : array (3,)
        Unit ENU vector towards the light source.
    heliostat_pos : array (3,) or None
        Reflection point (mirror centre), m ENU; None uses ``kin.mirror_center``.
    target : controller.config.Target or (plane_point, plane_normal)
        The target plane.
    offset_enu : array (3,)
        Measured centroid minus wanted centroid, m ENU (in the target plane).

    Returns
    -------
    Correction
        Add ``daz_steps``/``del_steps`` to the command to move the beam onto the wanted point.
        No soft-limit check here: the drive checks the new command.
    """
    pos = kin.mirror_center(az_steps, el_steps) if heliostat_pos is None else np.asarray(heliostat_pos, float)
    alpha, eps = kin.angles(az_steps, el_steps)
    jac = spot_jacobian(alpha, eps, source_dir, pos, target)
    offset = np.asarray(offset_enu, dtype=float)
    dtheta, *_ = np.linalg.lstsq(jac, -offset, rcond=None)
    residual = float(np.linalg.norm(jac @ dtheta + offset))
    daz = float(kin.azimuth.steps_float(alpha + dtheta[0])) - az_steps
    delv = float(kin.elevation.steps_float(eps + dtheta[1])) - el_steps
    return Correction(math.degrees(dtheta[0]), math.degrees(dtheta[1]), int(round(daz)), int(round(delv)),
                      residual)
