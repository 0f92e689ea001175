"""Where a heliostat's spot lands on a target, how large it is and whether a camera sees all of it.

**Size.** A lamp of diameter D at distance d from the mirror subtends α = D/d. The spot on a
target plane at distance L along the beam is the blur of independent contributions, which
add in quadrature per mirror axis (width w along the target's u axis, height h along v):

    σ² = (α L / 4)² + (2 σ_s L)² + (w |1 − L (1/f − 1/d)|)² / 12               (1)

— the lamp's disc imaged at L (a uniform disc of radius r has σ = r/2 per axis), the mirror's
slope error σ_s doubled on reflection, and the mirror of focal length f, which images a point
source at d at the distance d' of 1/d' = 1/f − 1/d (the thin-mirror equation), so that its
reflected bundle has width w |1 − L/d'| at L (a uniform band of width W has σ = W/√12). For
the sun d = ∞ and the bundle converges at f; a lamp a few tens of metres away is imaged far
behind the target and its spot is nearly as wide as the mirror. A beam meeting the plane
obliquely (cos θ = |b·N|) stretches the footprint by 1/cos θ along its in-plane direction d:

    Σ_spot = S diag(σ_u², σ_v²) Sᵀ,   S = I + (1/cos θ − 1) d dᵀ                 (2)

**Position.** The model aims the spot's centre at the aim point; a model error δp ~ N(0, Σ_p)
moves it by J δp, J = ∂(u, v)/∂p of the hit point (the reflected central ray meeting the
plane), so its covariance is

    Σ_pos = J Σ_p Jᵀ + (ε L)² I                                                 (3)

with ε a floor of the beam's error that no covariance knows: a model is not known better than
the noise of the measurements it was fitted to, and a real heliostat has effects no term has
(the callers take ε = 2 σ_n, the measured normal's noise doubled on reflection).

**In view.** A camera sees the target plane over a rectangle of half-size (H_u, H_v) about the
target centre (:class:`controller.geometry.target_frame.TargetFrame`: W × H). A spot aimed at
offset (o_u, o_v) from the centre is measurable when, per axis, its k-σ footprint displaced by
its centre's k-σ uncertainty stays a margin m inside:

    |o| + k (σ_spot + σ_pos) + m ≤ H,     k = 3                                  (4)

(3σ of a Gaussian spot holds 98.9 % of its power; the sum of the two σ is the conservative
bound of the footprint's edge). Parked beams are the converse: a standby spot must end at
least that far *outside* every view, H + k σ_spot + k_park σ_pos + m (its position at
:data:`PARK_POSITION_SIGMAS`) — sized where it is parked, not at the aim point: beside a wide
view the parked beam is longer and meets the plane more obliquely, so its spot and its
position's uncertainty are larger (:func:`park_clearance_m`).

Units: metres, radians; arrays broadcast over leading axes.

References
----------
.. [1] W. B. Stine, M. Geyer, "Power From The Sun", 2001, ch. 8.4 (beam spread of a heliostat
   image: sun shape, slope error, astigmatism, added in quadrature).
.. [2] C. J. Noone, M. Torrilhon, A. Mitsos, "Heliostat field optimization: a new
   computationally efficient model and biomimetic layout", Solar Energy 86, 2012
   (σ of the spot from independent Gaussian error sources, obliquity on the receiver).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.pose_batch import KinStack, aim_steps, forward_jacobian, normal_and_center, perturbed
from controller.geometry.target_frame import TargetFrame

SIGMAS = 3.0  # k of Eq. (4)
# A parked spot waits beside the view through a pass's captures, hundreds of them: its position
# is taken at this many σ of the model's covariance (its size at SIGMAS). At 3σ the 10,000
# field's parks put a few beams' edges into the view (2026-11-29), models seeded near the
# target's centre being less sure of a pose 25 m beside it than their covariance says.
PARK_POSITION_SIGMAS = 4.0
# park_clearance_m: the iteration converges while each step is at most this fraction of the last
CONTRACTION = 0.8
# park_clearance_m: how far (m) beyond the view's edge a park is looked for when the edge is out of reach
PARK_PROBES_M = (1.0, 2.0, 4.0, 8.0, 16.0)


@dataclass(frozen=True)
class MirrorOptics:
    """What sizes a heliostat's spot: mirror width and height (m), focal length (m) and slope
    error (rad, 1-σ)."""

    width_m: float
    height_m: float
    focal_m: float
    slope_error_rad: float

    @classmethod
    def from_config(cls, mirror) -> MirrorOptics:
        """From a :class:`controller.config.Mirror` (slope error in mrad)."""
        return cls(mirror.width_m, mirror.height_m, mirror.focal_length_m, 1e-3 * mirror.slope_error_mrad)

    @classmethod
    def stack(cls, mirrors) -> MirrorOptics:
        """H mirrors' optics as (H, 1) arrays, for a stack of heliostats' spots (one pose each
        or broadcast over K)."""
        each = [cls.from_config(m) for m in mirrors]
        return cls(*(np.array([getattr(o, f) for o in each])[:, None]
                     for f in ("width_m", "height_m", "focal_m", "slope_error_rad")))


def spot_covariance(distance_m, lamp_angle_rad, slope_error_rad, mirror_w_m, mirror_h_m, focal_m,
                    beam, normal, u_axis, v_axis, source_distance_m=np.inf) -> np.ndarray:
    """Σ_spot of Eq. (1)-(2), m², in the target plane's (u, v) axes, shape (..., 2, 2).

    ``distance_m`` L and ``lamp_angle_rad`` α (...,); ``slope_error_rad`` σ_s, mirror width,
    height and focal length (m, scalars or (...,)); ``beam`` (..., 3) the unit beam direction;
    ``normal``, ``u_axis``, ``v_axis`` ((3,) or broadcast against ``beam``) the target plane's
    unit normal and in-plane axes; ``source_distance_m`` d (...,) the lamp's distance from the
    mirror (∞ for the sun)."""
    L = np.asarray(distance_m, float)
    common = (np.asarray(lamp_angle_rad, float) * L / 4.0) ** 2 + (2.0 * np.asarray(slope_error_rad) * L) ** 2
    image = 1.0 / np.asarray(focal_m, float) - 1.0 / np.asarray(source_distance_m, float)  # 1/d'
    defocus = np.abs(1.0 - L * image)
    var_u = common + (np.asarray(mirror_w_m) * defocus) ** 2 / 12.0
    var_v = common + (np.asarray(mirror_h_m) * defocus) ** 2 / 12.0
    b = np.asarray(beam, float)
    cos_t = np.maximum(np.abs(_dot(b, normal)), 0.05)  # grazing: bounded stretch
    d = np.stack([_dot(b, u_axis), _dot(b, v_axis)], axis=-1)
    dn = np.linalg.norm(d, axis=-1, keepdims=True)
    d = np.where(dn > 1e-9, d / np.where(dn > 1e-9, dn, 1.0), 0.0)
    s = np.eye(2) + (1.0 / cos_t - 1.0)[..., None, None] * d[..., :, None] * d[..., None, :]
    base = np.zeros((*np.shape(var_u), 2, 2))
    base[..., 0, 0], base[..., 1, 1] = var_u, var_v
    return s @ base @ np.swapaxes(s, -1, -2)


def hit_uv(center, beam, plane_point, normal, u_axis, v_axis) -> np.ndarray:
    """(u, v) in m, from ``plane_point``, where rays from ``center`` (..., 3) along ``beam``
    (..., 3) meet the plane through ``plane_point`` with unit ``normal``: t = ((p₀ − o)·N)/(b·N).
    NaN where a ray is parallel to the plane or the plane is behind it. The plane's point and
    axes are (3,) or broadcast against the rays."""
    o, b = np.asarray(center, float), np.asarray(beam, float)
    p0 = np.asarray(plane_point, float)
    denom = _dot(b, normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _dot(p0 - o, normal) / denom
    t = np.where((np.abs(denom) > 1e-12) & (t >= 0.0), t, np.nan)
    hit = o + t[..., None] * b - p0
    return np.stack([_dot(hit, u_axis), _dot(hit, v_axis)], axis=-1)


def _dot(a, b) -> np.ndarray:
    return np.sum(np.asarray(a, float) * np.asarray(b, float), axis=-1)


def position_covariance(jacobian_uv: np.ndarray, model_covariance: np.ndarray) -> np.ndarray:
    """Σ_pos of Eq. (3), m², (..., 2, 2), from J (..., 2, p) in m per SI unit of each term and
    the model's covariance Σ_p (p, p), SI²."""
    j = np.asarray(jacobian_uv, float)
    return j @ np.asarray(model_covariance, float) @ np.swapaxes(j, -1, -2)


@dataclass(frozen=True, eq=False)  # numpy fields
class PredictedSpot:
    """Predicted spots (arrays over candidates): aim offset from the target centre (..., 2) m,
    the spot's 1-σ and its centre's 1-σ along u and v (..., 2) m."""

    offset_m: np.ndarray
    sigma_m: np.ndarray
    position_sigma_m: np.ndarray

    def reach_m(self, k: float = SIGMAS) -> np.ndarray:
        """How far from the target centre the k-σ footprint can reach along u and v (..., 2):
        |o| + k (σ_spot + σ_pos), the left side of Eq. (4) without the margin."""
        return np.abs(self.offset_m) + k * (self.sigma_m + self.position_sigma_m)

    def in_view(self, half_view_m, margin_m: float, k: float = SIGMAS) -> np.ndarray:
        """Eq. (4) on both axes, for a view of half-size ``half_view_m`` (2,) m: (...,) bool."""
        return np.all(self.reach_m(k) + margin_m <= np.asarray(half_view_m, float), axis=-1)


def predicted_spot(offset_m, spot_cov: np.ndarray, position_cov: np.ndarray) -> PredictedSpot:
    """:class:`PredictedSpot` from the aim offsets (..., 2) and the covariances of Eq. (2) and
    (3) (..., 2, 2): per axis σ = √Σ_ii (a conservative bound along the axes of a tilted
    ellipse: each marginal σ)."""
    return PredictedSpot(np.asarray(offset_m, float),
                         np.sqrt(np.clip(np.diagonal(spot_cov, axis1=-2, axis2=-1), 0.0, None)),
                         np.sqrt(np.clip(np.diagonal(position_cov, axis1=-2, axis2=-1), 0.0, None)))


def park_clearance_m(size_at: Callable[[np.ndarray], np.ndarray], half_view_m: float, margin_m: float,
                     shape: tuple[int, ...] = (), k: float = SIGMAS, rounds: int = 6,
                     tol_m: float = 0.05) -> np.ndarray:
    """The standby clearance (m, ``shape``) of spots sized where they are parked: the fixed
    point of c = H + k s(c) + m (Eq. 4's converse). ``size_at(c)`` gives s = σ_spot + σ_pos
    along the view's width (m, ``shape``; NaN where neither side is in reach) of the spot
    parked c from the target centre, the larger of the two sides.

    The iteration starts at the view's edge, c₀ = H + m, and climbs, s growing with c (the
    parked beam is longer and more oblique). While its steps shrink by a factor
    r < :data:`CONTRACTION` it converges, and what is left after ``rounds`` is the geometric
    tail, step · r / (1 − r), added. Where they do not (a spot whose position is uncertain by
    metres, as with the prior alone, grows faster aside than the offset), no clearance along the
    width holds at k σ: such a spot keeps the clearance reached when its steps stopped shrinking,
    at least c₁ = H + k s(c₀) + m, its size beside the view's edge (before 2026-11-29: c₁ even
    when the iteration had climbed past it, so a spot growing a little faster aside parked nearer).

    A spot out of reach on both sides at c₀ has no size there: it starts at the first of
    c₀ + :data:`PARK_PROBES_M` in reach, and where none is, no park beside the view is in reach
    (+∞). (Before 2026-11-29 it kept c₀ as if it were a point: a 10,000-heliostat night parked
    such heliostats 0.5 m beside the view, and their spots' tails stood in it for a whole lamp.)"""
    c0 = half_view_m + margin_m
    c = np.full(shape, c0)
    s = np.asarray(size_at(c), float)
    for probe in PARK_PROBES_M:
        unknown = ~np.isfinite(s)
        if not unknown.any():
            break
        farther = np.asarray(size_at(np.where(unknown, c0 + probe, c)), float)
        found = unknown & np.isfinite(farther)
        c, s = np.where(found, c0 + probe, c), np.where(found, farther, s)
    live = np.isfinite(s)
    c = np.where(live, c, np.inf)
    last = step = np.full(shape, np.inf)
    for i in range(rounds):
        at = np.where(live, c, c0)  # where a park is (being) sized; c₀ stands in for the others
        if i:
            s = np.asarray(size_at(at), float)
        grown = np.where(live & np.isfinite(s), half_view_m + k * s + margin_m, at)
        last, step = step, np.where(live, np.maximum(grown - at, 0.0), 0.0)
        diverging = live & (step > tol_m) & (step > CONTRACTION * last)
        c = np.where(diverging, c, c + step)
        live &= (step > tol_m) & ~diverging
        if not live.any():
            return c
    r = np.where(live, step / np.where(live, last, 1.0), 0.0)
    return c + step * r / (1.0 - r)


def park_clearances_m(kin: KinStack, optics: MirrorOptics, values: np.ndarray, covariance: np.ndarray,
                      frame: TargetFrame, margin_m: float, *, lamp=None, lamp_diameter_m: float = 0.0,
                      sun_dir=None, sun_angle_rad: float = 0.0, floor_rad: float = 0.0,
                      position_floor_m=0.0) -> np.ndarray:
    """The standby clearance (m, (H,)) of H heliostats beside ``frame``'s view
    (:func:`park_clearance_m`), each spot sized where it is parked on either side of the target
    centre (:func:`predict_spots` at the aim solve's steps there,
    :func:`controller.geometry.pose_batch.aim_steps`): ``kin`` their stack, ``values`` (H, p)
    and ``covariance`` (H, p, p) their models, ``optics`` fields (H, 1), the source and
    ``floor_rad`` as :func:`predict_spots` takes them; ``position_floor_m`` (H,) or scalar, the
    least σ of a spot's position (a heliostat's first-light σ). The position is taken at
    :data:`PARK_POSITION_SIGMAS` σ of the covariance (at least the floor at k σ): c = H +
    k σ_spot + max(k_park σ_pos, k floor) + m."""
    values = np.asarray(values, float)
    n = len(values)
    floor = np.broadcast_to(np.asarray(position_floor_m, float), (n,))[:, None]
    light = ({"lamp": lamp, "lamp_diameter_m": lamp_diameter_m} if lamp is not None
             else {"sun_dir": sun_dir, "sun_angle_rad": sun_angle_rad})

    def size_at(c: np.ndarray) -> np.ndarray:
        points = np.asarray(frame.center, float) + np.array([1.0, -1.0])[None, :, None] * c[:, None, None] \
            * np.asarray(frame.u, float)  # (H, 2, 3): both sides
        dirs = None if lamp is not None else np.broadcast_to(np.asarray(sun_dir, float), points.shape)
        steps, reach = aim_steps(kin.shaped(2), values[:, None, :], points, lamp=lamp, source_dirs=dirs)
        spot = predict_spots(kin, optics, values, covariance, steps, points, frame, floor_rad=floor_rad,
                             **light)
        position = PARK_POSITION_SIGMAS / SIGMAS * spot.position_sigma_m[..., 0]
        s = spot.sigma_m[..., 0] + np.maximum(position, floor)
        s = np.where(reach, s, -np.inf).max(axis=1)
        return np.where(np.isfinite(s), s, np.nan)

    return park_clearance_m(size_at, frame.width_m / 2.0, margin_m, (n,))


def predict_spots(kin: HeliostatKinematics | KinStack, optics: MirrorOptics, values: np.ndarray,
                  covariance: np.ndarray, steps: np.ndarray, aims: np.ndarray, frame: TargetFrame, *,
                  lamp=None, lamp_diameter_m: float | np.ndarray = 0.0, sun_dir=None,
                  sun_angle_rad: float = 0.0, floor_rad: float = 0.0, lamp_image: bool = False
                  ) -> PredictedSpot:
    """The spots of one heliostat at K poses on ``frame``'s plane (Eq. 1-3): aimed at ``aims``
    (K, 3) m ENU with motor ``steps`` (K, 2) by the model ``values`` (p,) SI, whose covariance
    is ``covariance`` (p, p) SI². The source is a lamp at ``lamp`` ((3,) or (K, 3) m ENU) of
    diameter ``lamp_diameter_m`` (its angular size is the diameter over its distance from the
    mirror), or the sun along ``sun_dir`` ((3,) unit ENU, towards it) of angular diameter
    ``sun_angle_rad``. The spot's size is taken along the aimed beam (mirror centre to aim
    point); its position's Jacobian is that of the reflected central ray's hit point
    (:func:`hit_uv`) by forward differences over the model's terms. ``floor_rad``: a beam error
    the covariance cannot know (what a measurement's noise leaves, effects no term has), added in
    quadrature as (floor · L)² on each axis. ``lamp_image``: focus the lamp at its own distance
    d (Eq. 1); False takes d = ∞, as for the sun (what the planner's measurability and the
    standby clearance use; it underestimates the spot of a lamp a few tens of metres away).

    A stack of H heliostats at once: ``kin`` a :class:`controller.geometry.pose_batch.KinStack`,
    ``values`` (H, p), ``covariance`` (H, p, p), ``steps`` (H, K, 2), ``aims`` and ``lamp``
    (H, K, 3), ``optics`` fields and ``lamp_diameter_m`` broadcast against (H, K), ``frame``'s
    ``center``, ``normal``, ``u``, ``v`` (3,) or (H, 1, 3)."""
    values = np.asarray(values, float)
    aims = np.asarray(aims, float)
    steps = np.asarray(steps, float)
    vals = perturbed(values)[..., :, None, :]  # (..., P, 1, p): the P parameter sets at every pose
    if hasattr(kin, "shaped"):
        kin = kin.shaped(vals.ndim - 1)
    n, c = normal_and_center(kin, vals, steps[..., None, :, :])  # (..., P, K, 3)
    plane = [_lift(np.asarray(x, float)) for x in (frame.center, frame.normal, frame.u, frame.v)]
    if lamp is not None:
        to_lamp = _lift(np.asarray(lamp, float)) - c
        s = to_lamp / np.linalg.norm(to_lamp, axis=-1, keepdims=True)
        lamp_m = np.linalg.norm(to_lamp[..., 0, :, :], axis=-1)
        angle = np.asarray(lamp_diameter_m, float) / lamp_m
        source_m = lamp_m if lamp_image else np.inf
    else:
        source_m = np.inf
        s = np.broadcast_to(np.asarray(sun_dir, float) / np.linalg.norm(sun_dir), c.shape)
        angle = np.full(aims.shape[:-1], float(sun_angle_rad))
    beam = 2.0 * np.sum(s * n, axis=-1, keepdims=True) * n - s
    uv = hit_uv(c, beam, *plane)  # (..., P, K, 2)
    j = np.nan_to_num(forward_jacobian(uv, axis=-3), nan=1e9)  # a beam off the plane: never in view
    to_aim = aims - c[..., 0, :, :]
    dist = np.linalg.norm(to_aim, axis=-1)
    o = optics
    cov = spot_covariance(dist, angle, o.slope_error_rad, o.width_m, o.height_m, o.focal_m,
                          to_aim / dist[..., None], frame.normal, frame.u, frame.v, source_m)
    rel = aims - np.asarray(frame.center, float)
    offset = np.stack([_dot(rel, frame.u), _dot(rel, frame.v)], axis=-1)
    pos_cov = position_covariance(j, np.asarray(covariance, float)[..., None, :, :])
    pos_cov = pos_cov + ((floor_rad * dist) ** 2)[..., None, None] * np.eye(2)
    return predicted_spot(offset, cov, pos_cov)


def _lift(x: np.ndarray) -> np.ndarray:
    """A per-pose array (..., K, 3) given the parameter-set axis: (..., 1, K, 3); (3,) as is."""
    return x if x.ndim < 2 else x[..., None, :, :]
