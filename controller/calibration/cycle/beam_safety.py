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

import numpy as np

from controller.config import Heliostat, PersonZone, Target
from controller.errors import HeliocalError
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.model.tracking import TrackingModel
from controller.geometry.pose_batch import normal_and_center
from controller.geometry.target_frame import TargetFrame
from controller.geometry.zones import rays_enter_any, zone_boxes, zone_entered

# How much closer (m) than both its ends a slew's beam may come to a camera's view: the sweep's
# samples on a curved path, not a bow towards the view.
BOW_TOLERANCE_M = 0.25
PATHS_KEPT = 8  # path_to's results kept per heliostat and source


class UnsafePath(HeliocalError):
    """No slew keeps the beam off the target (beam safety); nothing was sent."""


class BeamSafety:
    """The beam-safety geometry of ``heliostat`` under a source in direction ``source_dir``
    (unit ENU, towards the source) with its ``target`` (its ``frame``); ``others``: the plant's
    other targets, which slews must never cross either (their beams belong to other pipelines
    that run at the same time); ``zones``: the person zones the beam must never enter;
    ``model``: the heliostat's tracking model (None: the nominal kinematics)."""

    def __init__(self, heliostat: Heliostat, source_dir: np.ndarray, target: Target, frame: TargetFrame,
                 others: tuple[Target, ...] = (), zones: tuple[PersonZone, ...] = (),
                 model: TrackingModel | None = None) -> None:
        self.heliostat = heliostat
        self.kin = HeliostatKinematics.from_config(heliostat)
        self.source_dir = source_dir
        self.target = target
        self.frame = frame
        self.others = tuple((np.asarray(t.center_enu_m, float), TargetFrame.from_config(t, (1, 1)), t)
                            for t in others if t.id != target.id)
        self.zones, self.zone_ids = zone_boxes(zones), [z.id for z in zones]
        self.ray_model = (model or TrackingModel.zero()).values
        self._paths: dict[tuple, list[tuple[int, int]]] = {}  # path_to's last few

    def rays(self, poses) -> tuple[np.ndarray, np.ndarray]:
        """Mirror centres and unit reflected beams (N, 3) at ``poses`` (N, 2) motor steps."""
        n, c = normal_and_center(self.kin, self.ray_model, np.asarray(poses, float).reshape(-1, 2))
        s = np.asarray(self.source_dir, float)
        return c, 2.0 * (n @ s)[:, None] * n - s

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
        return self._lands_on(*self.rays(poses), self.frame.center, self.frame, self.target, margin_m)

    def on_other_target(self, poses, margin_m: float = 2.0) -> np.ndarray:
        """:meth:`beam_on_other_target` at each of ``poses`` (N, 2): (N,) bool."""
        return self._on_others(*self.rays(poses), margin_m)

    def _on_others(self, c: np.ndarray, b: np.ndarray, margin_m: float) -> np.ndarray:
        out = np.zeros(len(c), bool)
        for centre, f, t in self.others:
            out |= self._lands_on(c, b, centre, f, t, margin_m)
        return out

    def off_targets(self, az_steps: float, el_steps: float, margin_m: float = 2.0) -> bool:
        """Whether the ray at this pose lands on neither the target nor any of ``others`` (each
        grown by ``margin_m``) and enters no person zone: :meth:`beam_on_target`,
        :meth:`beam_on_other_target` and :meth:`beam_in_zone` on one trace of the ray."""
        c, b = self.rays([(az_steps, el_steps)])
        if self._lands_on(c, b, self.frame.center, self.frame, self.target, margin_m)[0]:
            return False
        if any(self._lands_on(c, b, centre, f, t, margin_m)[0] for centre, f, t in self.others):
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
        on = self._lands_on(c, b, self.frame.center, self.frame, self.target, 0.0)
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

    @staticmethod
    def _lands_on(c: np.ndarray, b: np.ndarray, center: np.ndarray, frame: TargetFrame, target: Target,
                  margin_m) -> np.ndarray:
        """Whether the rays from ``c`` along ``b`` (N, 3) land on ``target`` grown by ``margin_m``
        (m; or (u, v) m per axis; a ray pointing away from its plane does not)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((center - c) @ frame.normal) / (b @ frame.normal)
        hit = c + t[:, None] * b - center
        ok = np.isfinite(t) & (t >= 0.0)
        mu, mv = np.broadcast_to(np.asarray(margin_m, float), (2,))
        return (ok & (np.abs(hit @ frame.u) <= target.width_m / 2 + mu)
                & (np.abs(hit @ frame.v) <= target.height_m / 2 + mv))

    def reach_m(self) -> np.ndarray | None:
        """How far (u, v, m) beyond a target's edges a camera may see this heliostat's spot, or
        None when unknown: :meth:`path_to` then has no preference among the slews that keep the
        central ray off the targets."""
        return None

    def _outside(self, c: np.ndarray, b: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """(N, T): how far (m) each ray of ``c``, ``b`` (N, 3) lands outside each target's reach
        (the target, then ``others``; its edges moved out by ``reach`` (u, v)), the larger of the
        two axes' distances, negative inside, +inf where the ray misses the target's plane."""
        out = []
        for centre, f, t in ((self.frame.center, self.frame, self.target), *self.others):
            with np.errstate(divide="ignore", invalid="ignore"):
                d = ((centre - c) @ f.normal) / (b @ f.normal)
            hit = c + d[:, None] * b - centre
            e = np.maximum(np.abs(hit @ f.u) - t.width_m / 2 - reach[0],
                           np.abs(hit @ f.v) - t.height_m / 2 - reach[1])
            out.append(np.where(np.isfinite(d) & (d >= 0.0), e, np.inf))
        return np.stack(out, axis=1)

    def path_to(self, start: tuple[int, int], end: tuple[int, int], *,
                bow_ok: bool = False) -> list[tuple[int, int]]:
        """Waypoints from ``start`` to ``end`` (a point off the target) along which the beam
        never crosses the target nor any of the ``others``: both axes together, else elevation
        first, else azimuth first.
        The motion model moves each axis at its configured speed (acceleration ignored).
        Nor does it enter a person zone (a beam that starts in one may leave it).
        Of those slews, the first whose beam comes no closer to any target's camera view
        (:meth:`reach_m`) than both its ends do, or than outside the view's reach: a slew between
        two parks beside a target moves both axes, and its beam may bow towards the target on
        the way, its spot's tails into a camera that measures another beam (issue 42).
        ``bow_ok``: the first clear slew, bowing or not — whether a park exists, not its path
        (:func:`controller.calibration.beams.group.slot_parks`).
        Raises :class:`UnsafePath` when no such path exists; no waypoint when it stands there.
        The last few paths are kept: a slot's checks, the check of a leave pose and the park
        itself ask for the same one."""
        start, end = (int(start[0]), int(start[1])), (int(end[0]), int(end[1]))
        if start == end:
            return []
        key = (start, end, self.ray_model.tobytes())
        if key in self._paths:
            return list(self._paths[key])
        reach = None if bow_ok else self.reach_m()

        def never_back(flags: np.ndarray) -> bool:
            # A beam that starts on a target (in a zone) may leave it; once off it must never enter.
            off = np.flatnonzero(~flags)
            return not len(off) or not flags[off[0]:].any()

        def judge(plan: list[tuple[int, int]]) -> tuple[bool, bool]:
            """(the central ray stays off the targets and zones, the spot comes no closer to a view)."""
            poses = np.vstack([self._sweep(a, b) for a, b in zip([start] + plan[:-1], plan, strict=True)])
            c, b = self.rays(np.vstack([np.asarray(start, float)[None], poses]))  # traced once for all
            safe = (never_back(self._lands_on(c, b, self.frame.center, self.frame, self.target, 2.0))
                    and never_back(self._on_others(c, b, 2.0)) and never_back(self._in_zone(c, b)))
            if not safe or reach is None:
                return safe, safe
            e = self._outside(c, b, reach)
            return True, bool((e >= np.minimum(np.minimum(e[0], e[-1]), 0.0) - BOW_TOLERANCE_M).all())

        plans = ([end], [(start[0], end[1]), end], [(end[0], start[1]), end])
        first = None
        for plan in plans:
            safe, close = judge(plan)
            if close:
                first = plan
                break
            if safe and first is None:
                first = plan
        if first is not None:
            path = [p for p in first if p != start]
            if not bow_ok:
                if len(self._paths) >= PATHS_KEPT:
                    del self._paths[next(iter(self._paths))]
                self._paths[key] = path
            return list(path)
        raise UnsafePath(f"{self.heliostat.id}: no slew from {start} to standby {end} keeps the beam "
                         "off the targets")
