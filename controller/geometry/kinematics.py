"""Two-axis heliostat kinematics: motor steps <-> ENU mirror normal, and aiming.

Convention (that of the Jülich heliostats in PAINT/ARTIST, checked on the AA39 records, see
docs/geometry.md). The first joint (elevation, angle ε) rotates about East, ε measured from
the zenith; the second joint (azimuth, angle α) rotates about the mirror's own "up" axis,
which the first joint carries; at α = 0 the mirror faces south, positive α turns the normal
east. With right-handed rotation matrices R_e, R_u about East and Up,

    R(α, ε) = R_e(ε − π/2) · R_u(α),                                  (1)

maps the mirror's body frame, in which the normal is b = (0, −1, 0) (the ARTIST body frame:
the mirror facing south), to ENU, so

    n(α, ε) = R(α, ε) b = (sin α, −sin ε cos α, cos ε cos α),          (2)

and the inverse is α = arcsin(n_E), ε = atan2(−n_N, n_U).             (3)

The reflecting surface's centre is displaced from the pivot by the concentrator translation
c (body frame, m): p_mirror = p_pivot + R(α, ε) c. AA39 has c = (0, 0.175, 0).

References
----------
.. [1] M. Pargmann et al., ARTIST, Nature Communications 15, 6997, 2024; rigid-body
   kinematic ``artist/field/kinematic_rigid_body.py`` (joint 1 about E, joint 2 about U,
   concentrator translation applied last).
.. [2] PAINT database of the Jülich solar tower (Nature Energy 2026): heliostat properties.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controller.errors import LimitError
from controller.geometry.actuators import LinearActuator
from controller.geometry.aiming import aim_normal, intersect_plane, reflected_beam
from controller.geometry.frames import wgs84_to_enu
from controller.geometry.vectors import unit

BODY_NORMAL = np.array([0.0, -1.0, 0.0])


def rotation_e(angle_rad: float) -> np.ndarray:
    """Right-handed rotation about East (x) by ``angle_rad``: north tips up for positive angles."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_n(angle_rad: float) -> np.ndarray:
    """Right-handed rotation about North (y) by ``angle_rad``: up tips east for positive angles."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_u(angle_rad: float) -> np.ndarray:
    """Right-handed rotation about Up (z) by ``angle_rad``: east turns north for positive angles."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def joint_rotation(alpha_rad: float, eps_rad: float) -> np.ndarray:
    """R(α, ε) of Eq. (1): body frame -> ENU for azimuth α and elevation-from-zenith ε, rad."""
    return rotation_e(eps_rad - math.pi / 2.0) @ rotation_u(alpha_rad)


def normal_from_angles(alpha_rad, eps_rad) -> np.ndarray:
    """Unit ENU mirror normal of Eq. (2) for joint angles α, ε in rad. Shape (..., 3)."""
    a, e = np.asarray(alpha_rad, dtype=float), np.asarray(eps_rad, dtype=float)
    return np.stack([np.sin(a), -np.sin(e) * np.cos(a), np.cos(e) * np.cos(a)], axis=-1)


def angles_from_normal(normal) -> tuple[float, float]:
    """Joint angles (α, ε), rad, of a unit ENU normal, Eq. (3). α in [−π/2, π/2]."""
    n = unit(normal)
    return float(np.arcsin(np.clip(n[0], -1.0, 1.0))), float(np.arctan2(-n[1], n[2]))


@dataclass(frozen=True, eq=False)  # eq=False: numpy fields; compare instances by identity
class HeliostatKinematics:
    """Kinematic model of one heliostat: pivot position, two linear actuators, mirror offset.

    ``position`` is the pivot (intersection of the joint axes), m ENU; ``concentrator_translation``
    is c of the module docstring, m, body frame.
    """

    heliostat_id: str
    position: np.ndarray
    azimuth: LinearActuator
    elevation: LinearActuator
    concentrator_translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_config(cls, heliostat) -> HeliostatKinematics:
        """From a :class:`controller.config.Heliostat` (soft limits from its axes, c from its
        ``concentrator_translation_m``)."""
        return cls(heliostat.id, np.asarray(heliostat.position_enu_m, dtype=float),
                   LinearActuator.from_config("azimuth", heliostat.axes.azimuth),
                   LinearActuator.from_config("elevation", heliostat.axes.elevation),
                   np.asarray(heliostat.concentrator_translation_m, dtype=float))

    @classmethod
    def from_aa39(cls, properties: dict, origin_wgs84=None,
                  heliostat_id: str = "AA39") -> HeliostatKinematics:
        """From a PAINT/ARTIST ``heliostat-properties`` dict.

        ``actuators[0]`` is the elevation joint (about East), ``actuators[1]`` the azimuth joint.
        The WGS84 ``heliostat_position`` is converted to ENU about ``origin_wgs84``
        (lat_deg, lon_deg, alt_m); without an origin the heliostat itself is the origin.
        """
        kp = properties["kinematics_properties"]
        lat, lon, alt = properties["heliostat_position"]
        pos = np.zeros(3) if origin_wgs84 is None else wgs84_to_enu(lat, lon, alt, *origin_wgs84)
        conc = np.array([kp.get("concentrator_translation_e", 0.0), kp.get("concentrator_translation_n", 0.0),
                         kp.get("concentrator_translation_u", 0.0)], dtype=float)
        return cls(heliostat_id, np.asarray(pos, dtype=float),
                   LinearActuator.from_aa39("azimuth", kp["actuators"][1]),
                   LinearActuator.from_aa39("elevation", kp["actuators"][0]), conc)

    def angles(self, az_steps: float, el_steps: float) -> tuple[float, float]:
        """Joint angles (α, ε), rad, at the given motor steps (no limit check)."""
        return float(self.azimuth.angle(az_steps)), float(self.elevation.angle(el_steps))

    def normal(self, az_steps: float, el_steps: float) -> np.ndarray:
        """Unit ENU mirror normal at the given motor steps. Shape (3,)."""
        return normal_from_angles(*self.angles(az_steps, el_steps))

    def mirror_center(self, az_steps: float, el_steps: float) -> np.ndarray:
        """Centre of the reflecting surface, m ENU: pivot + R(α, ε) c."""
        rot = joint_rotation(*self.angles(az_steps, el_steps))
        return self.position + rot @ self.concentrator_translation

    def steps_for_angles(self, alpha_rad: float, eps_rad: float) -> tuple[int, int]:
        """Whole motor steps (az, el) for joint angles; LimitError when outside the soft limits."""
        return self.azimuth.steps(alpha_rad), self.elevation.steps(eps_rad)

    def steps_for_normal(self, normal) -> tuple[int, int]:
        """Motor steps (az_steps, el_steps) that point the mirror normal along ``normal`` (ENU).

        Raises LimitError (naming the axis and value) when the joint angles of Eq. (3) are out
        of the actuators' reach or need steps outside the soft limits. Eq. (3) is unique for
        α in [−π/2, π/2], so a normal slightly below the horizon (stow) is handled too.
        """
        return self.steps_for_angles(*angles_from_normal(normal))

    def aim(self, source_dir, aim_point, iterations: int = 4, *, lamp_position=None) -> tuple[int, int]:
        """Motor steps that reflect light from ``source_dir`` (unit ENU, towards the source)
        onto ``aim_point`` (m ENU).

        The mirror centre moves with the pose when c ≠ 0, so the bisector (aiming.aim_normal) is
        re-evaluated at the new centre a few times; each pass shrinks the error by |c|/distance.
        For a lamp (a near source) pass ``lamp_position`` (m ENU): the source direction is then
        taken from the mirror centre each pass and ``source_dir`` is ignored (may be None).
        """
        center = self.position + joint_rotation(0.0, 0.0) @ self.concentrator_translation
        alpha = eps = 0.0
        for _ in range(iterations):
            if lamp_position is not None:
                source_dir = unit(np.asarray(lamp_position, dtype=float) - center)
            alpha, eps = angles_from_normal(aim_normal(source_dir, center, aim_point))
            center = self.position + joint_rotation(alpha, eps) @ self.concentrator_translation
        if lamp_position is not None:
            source_dir = unit(np.asarray(lamp_position, dtype=float) - center)
        if aim_normal(source_dir, center, aim_point)[2] <= 0.0:
            raise LimitError(f"heliostat {self.heliostat_id}: aim point {np.round(aim_point, 3).tolist()} "
                             "needs a normal below the horizon")
        return self.steps_for_angles(alpha, eps)

    def beam(self, az_steps: float, el_steps: float, source_dir) -> np.ndarray:
        """Unit direction of the reflected beam at the given steps."""
        return reflected_beam(source_dir, self.normal(az_steps, el_steps))

    def spot(self, az_steps: float, el_steps: float, source_dir, plane_point, plane_normal) -> np.ndarray:
        """Where the reflected beam's axis meets a plane (e.g. the target), m ENU."""
        origin = self.mirror_center(az_steps, el_steps)
        return intersect_plane(origin, self.beam(az_steps, el_steps, source_dir), plane_point, plane_normal)
