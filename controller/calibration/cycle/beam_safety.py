"""Beam safety of one heliostat: where its reflected central ray lands at a pose (on its target,
on another target, into a person zone) and slews that keep it off them (docs/campaigns.md,
"Beam safety"). Every standby pose, slew, approach and lamp change is checked here before
anything moves.

The ray is traced with the heliostat's tracking model when it has one (the poses are computed
with it: a heliostat of a large field 10 mrad off nominal puts its beam 15 m from where the
nominal kinematics would, at 370 m), else with the nominal kinematics; the target is grown by
a margin for the spot's radius and the model's error. Many poses are traced at once (a slew's
samples) through :mod:`controller.geometry.pose_batch`."""

from __future__ import annotations

import functools

import numpy as np

from controller.config import Heliostat, PersonZone, Target
from controller.errors import HeliocalError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import normal_and_center
from controller.geometry.spot import hit_uv
from controller.geometry.target_frame import TargetFrame
from controller.geometry.zones import rays_enter_any, zone_boxes, zone_entered

# A heliostat parked beside its target waits there rather than slide along the view to its own
# standby when its approach from there is at most this much slower (s): the target waits for it.
WAIT_SLOWER_S = 1.0
# ... and when it stands no deeper inside the path's margin than its standby lies, plus this (m):
# a step of the solved standby moves its ray by about a centimetre.
WAIT_DEPTH_SLACK_M = 0.05


class UnsafePath(HeliocalError):
    """No slew keeps the beam off the target (beam safety); nothing was sent."""


class BeamSafety:
    """The beam-safety geometry of ``heliostat`` under a source in direction ``source_dir``
    (unit ENU, towards the source) with its ``target`` (its ``frame``); ``others``: the plant's
    other targets, which slews must never cross either (their beams belong to other pipelines
    that run at the same time); ``zones``: the person zones the beam must never enter;
    ``model``: the heliostat's tracking model (None: the nominal kinematics); ``lamp``: the
    lamp's position (m ENU; None for the sun), from which each pose's ray takes its light."""

    def __init__(self, heliostat: Heliostat, source_dir: np.ndarray, target: Target, frame: TargetFrame,
                 others: tuple[Target, ...] = (), zones: tuple[PersonZone, ...] = (),
                 model: TrackingModel | None = None, lamp=None) -> None:
        self.heliostat = heliostat
        self.kin = HeliostatKinematics.from_config(heliostat)
        self.source_dir = source_dir
        self.lamp = None if lamp is None else np.asarray(lamp, float)
        self.target = target
        self.frame = frame
        self.others = _other_frames(tuple(others), target.id)
        self._planes = _planes(frame, target, self.others)
        self.zones, self.zone_ids = zone_boxes(zones), [z.id for z in zones]
        self.ray_model = (model or TrackingModel.zero()).values
        self._poses: dict[tuple, tuple | str] = {}  # kept's

    def kept(self, key: tuple, compute) -> tuple:
        """``compute()``'s pose (or path, or identity step), kept by ``key`` and the ray's model: a
        pointing is asked for its aim and standby steps, its slews and its identity step several
        times (a slot's checks, preparing, each park, the capture), and each answer traces the
        beam past the targets and through the person zones. An UnsafePath is kept as its message."""
        key = self._with_model(key)
        kept = self._poses.get(key)
        if kept is None:
            try:
                kept = compute()
            except UnsafePath as exc:
                kept = str(exc)
            self._poses[key] = kept
        if isinstance(kept, str):
            raise UnsafePath(kept)
        return kept

    def _with_model(self, key: tuple) -> tuple:
        return (*key, self.ray_model.tobytes())

    def rays(self, poses, values=None) -> tuple[np.ndarray, np.ndarray]:
        """Mirror centres and unit reflected beams (N, 3) at ``poses`` (N, 2) motor steps, traced
        with the ray model (or the model terms ``values``: :class:`TrackingModel`'s). A
        lamp's light comes from the lamp to each pose's mirror centre, as the poses were solved
        (:func:`controller.geometry.model.tracking.model_aim`): the centre moves with the pose
        and the model's position terms, and a lamp tens of metres away sees that parallax
        (before 2026-11-30 the ray took the direction from the heliostat's nominal position, and
        a standby solved to land just outside a path's margin was traced inside it; issue 42)."""
        n, c = normal_and_center(self.kin, self.ray_model if values is None else values,
                                 np.asarray(poses, float).reshape(-1, 2))
        return c, self.reflected(n, c)

    def plane_uv(self, poses, values=None) -> np.ndarray:
        """(u, v) m from the view's centre where the beams at ``poses`` (:meth:`rays`) meet the
        target's plane (N, 2); NaN where one does not."""
        f = self.frame
        return hit_uv(*self.rays(poses, values), f.center, f.normal, f.u, f.v)

    def reflected(self, n: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Unit reflected beams (N, 3) of mirrors with unit normals ``n`` at centres ``c`` (N, 3,
        m ENU) under this source: b = 2 (n·s) n − s, s towards the source (from each centre for a
        lamp)."""
        if self.lamp is None:
            s = np.broadcast_to(np.asarray(self.source_dir, float), n.shape)
        else:
            s = self.lamp - c
            s = s / np.linalg.norm(s, axis=1, keepdims=True)
        return 2.0 * np.sum(n * s, axis=1, keepdims=True) * n - s

    def beam_on_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the reflected central ray lands on the target grown by ``margin_m``
        (spot radius plus model error)."""
        return bool(self.on_target([(az_steps, el_steps)], margin_m)[0])

    def beam_on_other_target(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the reflected central ray lands on one of the ``others`` targets grown by
        ``margin_m``."""
        return bool(self.on_other_target([(az_steps, el_steps)], margin_m)[0])

    def on_target(self, poses, margin_m: float = 2.0) -> np.ndarray:
        """:meth:`beam_on_target` at each of ``poses`` (N, 2): (N,) bool."""
        return self._depths(*self.rays(poses), margin_m)[:, 0] >= 0.0

    def on_other_target(self, poses, margin_m: float = 2.0) -> np.ndarray:
        """:meth:`beam_on_other_target` at each of ``poses`` (N, 2): (N,) bool."""
        return self._on_others(*self.rays(poses), margin_m)

    def _on_others(self, c: np.ndarray, b: np.ndarray, margin_m: float) -> np.ndarray:
        return self._others_depth(c, b, margin_m) >= 0.0

    def _others_depth(self, c: np.ndarray, b: np.ndarray, margin_m) -> np.ndarray:
        """The deepest :meth:`_depths` of the rays in any of the ``others``: (N,)."""
        return self._depths(c, b, margin_m)[:, 1]

    def off_targets(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the ray at this pose lands on neither the target nor any of ``others`` (each
        grown by ``margin_m``) and enters no person zone: :meth:`beam_on_target`,
        :meth:`beam_on_other_target` and :meth:`beam_in_zone` on one trace of the ray."""
        c, b = self.rays([(az_steps, el_steps)])
        if (self._depths(c, b, margin_m) >= 0.0).any():
            return False
        return not self.zone_ids or zone_entered(c[0], b[0], self.zones, self._stop(c, b)[0]) is None

    def beam_in_zone(self, az_steps: float, el_steps: float) -> str | None:
        """The id of the person zone the reflected central ray enters at this pose, or None; a
        beam that lands on the target ends there."""
        if not self.zone_ids:
            return None
        c, b = self.rays([(az_steps, el_steps)])
        stop = self._stop(c, b)[0]
        k = zone_entered(c[0], b[0], self.zones, stop)
        return None if k is None else self.zone_ids[k]

    def in_zone(self, poses) -> np.ndarray:
        """Whether the ray enters a person zone at each of ``poses`` (N, 2): (N,) bool."""
        if not self.zone_ids:
            return np.zeros(len(np.asarray(poses).reshape(-1, 2)), bool)
        return self._in_zone(*self.rays(poses))

    def _in_zone(self, c: np.ndarray, b: np.ndarray) -> np.ndarray:
        if not self.zone_ids:
            return np.zeros(len(c), bool)
        return rays_enter_any(c, b, self.zones, self._stop(c, b))

    def _stop(self, c: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Where each ray ends: on the target (distance along the ray), else never."""
        on = self._depths(c, b, 0.0)[:, 0] >= 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.frame.center - c) @ self.frame.normal) / (b @ self.frame.normal)
        return np.where(on, t, np.inf)

    def _sweep(self, a: tuple[float, float], b: tuple[float, float], samples: int = 120) -> np.ndarray:
        """Poses (az, el steps) along a slew from ``a`` to ``b``, each axis moving at its
        configured speed (acceleration ignored): (samples, 2) (one pose for no move)."""
        ax = self.heliostat.axes
        speed = np.array([ax.azimuth.speed_steps_per_s, ax.elevation.speed_steps_per_s])
        a_, b_ = np.asarray(a, float), np.asarray(b, float)
        dur = np.abs(b_ - a_) / speed
        total = float(dur.max())
        t = np.linspace(0.0, total, samples if total > 0 else 1)[:, None]
        frac = np.where(dur > 0, np.minimum(1.0, t / np.where(dur > 0, dur, 1.0)), 1.0)
        return a_ + frac * (b_ - a_)

    def _depths(self, c: np.ndarray, b: np.ndarray, margin_m) -> np.ndarray:
        """How far (m) inside the target and, the deepest, inside the ``others``, each grown by
        ``margin_m`` (m; or (u, v) m per axis; or (N, 2), one per ray), the rays from ``c`` along ``b``
        (N, 3) land: (N, 2),
        min(w/2 + m_u − |u|, h/2 + m_v − |v|) at the hit (u, v) in a target's plane, negative
        outside, −∞ for a ray pointing away from the plane; ≥ 0: it lands on it. Every plane at
        once (:func:`_planes`): a slew's check traces hundreds of rays past three targets,
        thousands of times a night. With q = c − centre, the ray meets a plane at
        t = −(q·n)/(b·n), and (u, v) = (q·u + t b·u, q·v + t b·v): two products of the rays with
        the planes' axes, (N, 3) by (3, 3T)."""
        axes, offsets, half = self._planes
        planes = len(half)
        q, d = c @ axes - offsets, b @ axes  # (q·n, q·u, q·v) and (b·n, b·u, b·v), T columns each
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -q[:, :planes] / d[:, :planes]
            hu = q[:, planes:2 * planes] + t * d[:, planes:2 * planes]
            hv = q[:, 2 * planes:] + t * d[:, 2 * planes:]
        m = np.asarray(margin_m, float)
        mu, mv = (m[:, :1], m[:, 1:]) if m.ndim == 2 else np.broadcast_to(m, (2,))
        depth = np.minimum(half[:, 0] + mu - np.abs(hu), half[:, 1] + mv - np.abs(hv))
        depth = np.where(np.isfinite(t) & (t >= 0.0), depth, -np.inf)
        return np.stack([depth[:, 0], depth[:, 1:].max(axis=1, initial=-np.inf)], axis=1)

    def may_wait_at(self, pose, standby, aim, margin_m: float) -> bool:
        """Whether a heliostat about to take its turn may wait at ``pose`` (motor steps, where it
        stands still) rather than slew to ``standby`` first. Its beam there lands off every
        target grown by ``margin_m`` (m, or (u, v) m: the cycle gives :meth:`path_margin_m`), or
        no deeper inside one than its standby's beam (:data:`WAIT_DEPTH_SLACK_M`: a far
        heliostat's footprint at the aim can reach beyond its park clearance, its standby then
        inside the margin, and a slew that starts inside may slide along it, :meth:`path_to`),
        and in no person zone. Its approach from ``pose`` to ``aim`` takes no more than
        :data:`WAIT_SLOWER_S` longer than from ``standby`` (it is parked beside the target: the
        approach is made while the target waits for it) and keeps it off the other targets
        (grown by 2 m) and out of the person zones. A slew between two parks beside a target
        slides the spot along the view's edge while other beams are measured there: the model's
        ray keeps the path's margin, the true spot need not. Whole-plan nights had such slews
        from a lamp change's standby put a spot's tails into a capture (issue 42). A wait
        within the view margin (the park's 0.5 m slack left out) put more there: 152 captures
        in a whole plan."""
        if tuple(pose) == tuple(standby):
            return False
        if self._slew_s(pose, aim) > self._slew_s(standby, aim) + WAIT_SLOWER_S:
            return False
        c, b = self.rays([pose, standby])
        # As far out as its standby: off the targets grown by the margin, or no deeper inside than
        # the standby (a park whose footprint at the aim reaches beyond its clearance lies inside).
        depth = self._depths(c, b, margin_m)
        deepest = np.where(depth[1] >= 0.0, depth[1] + WAIT_DEPTH_SLACK_M, 0.0)
        if (depth[0] >= deepest).any() or self._in_zone(c[:1], b[:1])[0]:
            return False
        c, b = self.rays(self._sweep(pose, aim))
        return not (self._on_others(c, b, 2.0).any() or self._in_zone(c, b).any())

    def _slew_s(self, a, b) -> float:
        """Seconds a slew from ``a`` to ``b`` (motor steps) takes, each axis at its configured
        speed (acceleration ignored, as in :meth:`_sweep`)."""
        ax = self.heliostat.axes
        return max(abs(float(b[0]) - float(a[0])) / ax.azimuth.speed_steps_per_s,
                   abs(float(b[1]) - float(a[1])) / ax.elevation.speed_steps_per_s)

    def path_margin_m(self) -> float | np.ndarray:
        """How far (m; or (u, v) m) beyond each target's edges a slew keeps the central ray: 2 m
        here; a pointing that knows its spot keeps the spot out of the cameras' views."""
        return 2.0

    def view_margin_m(self) -> float | np.ndarray:
        """How far (m; or (u, v) m) beyond each target's edges the central ray puts the spot's
        footprint into a camera's view: :meth:`path_margin_m` here; a pointing that knows its
        spot leaves out the slack a park keeps beyond it: a heliostat whose park failed may stay
        where its ray is off every target grown by this (:func:`park.safe_where_it_stands`)."""
        return self.path_margin_m()

    def path_to(self, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]:
        """Waypoints from ``start`` to ``end`` (a point off the target) along which the beam
        never crosses the target nor any of the ``others`` grown by :meth:`path_margin_m`: both
        axes together, else elevation first, else azimuth first.
        The motion model moves each axis at its configured speed (acceleration ignored).
        Nor does it enter a person zone (a beam that starts in one may leave it).
        Raises :class:`UnsafePath` when no such path exists; no waypoint when it stands there."""
        if tuple(start) == tuple(end):
            return []
        margin = self.path_margin_m()
        # A slot's checks ask for the slews its cycle takes again (from where it stands, from
        # its aim): each answer traces three sweeps of 120 poses.
        key = self._path_key(start, end, margin)
        return list(self.kept(key, lambda: tuple(self._path(start, end, margin))))

    def warm_paths(self, starts, end: tuple[int, int]) -> None:
        """Trace the direct slews from each of ``starts`` (poses, or None) to ``end`` in one
        evaluation of the model and keep those that are clear for :meth:`path_to`, which then
        answers them without tracing (the others it plans as ever). A slot's check asks for three
        slews of each heliostat (:func:`controller.calibration.beams.group.slot_parks`): one trace
        of their 363 poses costs about what one of 121 does."""
        todo, poses = self.direct_slews(starts, end)
        if todo:
            inside = self._inside(*self.rays(np.vstack(poses)), self.path_margin_m())
            self.keep_clear(todo, end, poses, inside)

    def direct_slews(self, starts, end: tuple[int, int]) -> tuple[list[tuple], list[np.ndarray]]:
        """Those of ``starts`` (poses, or None) whose direct slew to ``end`` is not kept yet, and
        the poses of each one's slew (its start, then its sweep)."""
        margin = self.path_margin_m()
        todo = [s for s in dict.fromkeys(tuple(s) for s in starts if s is not None) if s != tuple(end)
                and self._with_model(self._path_key(s, end, margin)) not in self._poses]
        return todo, [np.vstack([np.asarray(s, float)[None], self._sweep(s, end)]) for s in todo]

    def keep_clear(self, todo: list[tuple], end: tuple[int, int], poses: list[np.ndarray],
                   inside: np.ndarray) -> None:
        """Keep for :meth:`path_to` the direct slews of :meth:`direct_slews` (``todo``, ``poses``)
        that are clear by ``inside``: :meth:`_inside` of their poses' rays one after the other, with
        :meth:`path_margin_m`."""
        margin = self.path_margin_m()
        at = 0
        for s, p in zip(todo, poses, strict=True):
            if _never_back(inside[at:at + len(p)]):
                self.kept(self._path_key(s, end, margin), lambda: (end,))
            at += len(p)

    @staticmethod
    def _path_key(start, end, margin) -> tuple:
        return ("path", *map(float, start), *map(float, end), np.asarray(margin, float).tobytes())

    def _inside(self, c: np.ndarray, b: np.ndarray, margin) -> np.ndarray:
        """(N, 3) bool: whether each ray lands on the target, on one of the ``others`` (each grown
        by ``margin``) and in a person zone — what a slew must not enter (:func:`_never_back`)."""
        return np.column_stack([self._depths(c, b, margin) >= 0.0, self._in_zone(c, b)])

    def _path(self, start: tuple[int, int], end: tuple[int, int], margin) -> list[tuple[int, int]]:
        """:meth:`path_to`'s waypoints, traced with the target grown by ``margin``."""

        def clear(plan: list[tuple[int, int]]) -> bool:
            poses = np.vstack([self._sweep(a, b) for a, b in zip([start] + plan[:-1], plan, strict=True)])
            c, b = self.rays(np.vstack([np.asarray(start, float)[None], poses]))  # traced once for all three
            return _never_back(self._inside(c, b, margin))

        plans = ([end], [(start[0], end[1]), end], [(end[0], start[1]), end])
        for plan in plans:
            if clear(plan):
                return [p for p in plan if p != start]
        raise UnsafePath(f"{self.heliostat.id}: no slew from {start} to standby {end} keeps the beam "
                         "off the targets")


def _never_back(inside: np.ndarray) -> bool:
    """Whether, along a slew's poses (rows), the beam never enters what it was not in at the
    start: a beam that starts on a target (in a zone) may leave it; once off it must never enter.
    ``inside``: (poses, checks) bool, a column per target set and the person zones."""
    entered = np.logical_or.accumulate(~inside, axis=0) & inside  # inside again after once outside
    return not entered.any()


def _planes(frame: TargetFrame, target: Target, others: tuple) -> tuple[np.ndarray, ...]:
    """(axes (3, 3T): the normals, then the u axes, then the v axes of the T planes as columns;
    offsets (3T,): each plane's centre dotted with them; half width and height (T, 2)) of
    ``target`` seen through ``frame`` and each of ``others`` (:func:`_other_frames`), the target
    first: the planes :meth:`BeamSafety._depths` traces every ray past at once."""
    rows = [(frame.center, frame, target), *others]
    centre = np.array([c for c, _, _ in rows], float)
    axes = np.vstack([np.array([getattr(f, a) for _, f, _ in rows], float) for a in ("normal", "u", "v")])
    return (np.ascontiguousarray(axes.T), np.einsum("ak,ak->a", axes, np.tile(centre, (3, 1))),
            np.array([(t.width_m / 2, t.height_m / 2) for _, _, t in rows], float))


@functools.lru_cache(maxsize=64)
def _other_frames(others: tuple[Target, ...], target_id: str) -> tuple:
    """(centre, view of 1 × 1 pixel, target) of each of ``others`` but ``target_id``: the same
    for every heliostat of a plant (configs are frozen), asked for with each of a night's
    pointings (three per measurement). The arrays are read-only, being shared."""
    out = []
    for t in others:
        if t.id == target_id:
            continue
        frame = TargetFrame.from_config(t, (1, 1))
        centre = np.asarray(t.center_enu_m, float)
        for a in (centre, frame.center, frame.normal, frame.u, frame.v):
            a.flags.writeable = False
        out.append((centre, frame, t))
    return tuple(out)
